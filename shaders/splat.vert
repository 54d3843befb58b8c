#version 430
// One instanced quad (triangle strip of 4 vertices) per Gaussian, in back-to-front order. The fragment shader
// evaluates the Gaussian at gl_FragCoord (pixel centres at i + 0.5) with flat per-splat data: interpolated
// offsets would be exact in theory, but llvmpipe interpolates clipped, very large triangles inexactly.
#include "splat_common.glsl"

layout(std430, binding = 2) readonly buffer SplatBuffer { Splat splats[]; };
layout(std430, binding = 3) readonly buffer OrderBuffer { uint order[]; };

uniform vec2 u_viewport;
uniform int u_mode;  // 0: colour, 1: depth

flat out vec4 v_centre_opacity;  // xy: centre (window px), w: opacity
flat out vec3 v_conic;
flat out vec3 v_feature;         // composited feature: colour or depth

void main() {
    Splat s = splats[order[gl_InstanceID]];
    v_centre_opacity = vec4(s.centre.xy, 0.0, s.centre.w);
    v_conic = s.conic.xyz;
    v_feature = u_mode == 1 ? vec3(s.centre.z) : s.feature.rgb;
    if (s.centre.w <= 0.0) {  // culled: a degenerate quad outside the clip volume
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        return;
    }
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    vec2 window = s.centre.xy + corner.x * s.axes.xy + corner.y * s.axes.zw;
    gl_Position = vec4(window / u_viewport * 2.0 - 1.0, 0.0, 1.0);
}
