#version 430
// One instanced quad (triangle strip of 4 vertices) per Gaussian, in back-to-front order. The fragment shader
// evaluates the Gaussian at gl_FragCoord (pixel centres at i + 0.5) with flat per-splat data: interpolated
// offsets would be exact in theory, but llvmpipe interpolates clipped, very large triangles inexactly.
// Shared by the colour pass (splat.frag) and the id pass (splat_id.frag).
#include "splat_common.glsl"

layout(std430, binding = 2) readonly buffer SplatBuffer { Splat splats[]; };
layout(std430, binding = 3) readonly buffer OrderBuffer { uint order[]; };

uniform vec2 u_viewport;
uniform uint u_first;        // first sorted position of this draw (a slice of the sorted order)
uniform int u_mode;           // 0: colour, 1: depth
uniform int u_style;          // STYLE_*
uniform float u_point_px;     // disc radius of STYLE_POINTS
uniform float u_min_opacity;  // points and ellipsoids: Gaussians below this opacity are not drawn

flat out vec4 v_centre_opacity;  // xy: centre (window px), w: opacity
flat out vec3 v_conic;
flat out vec3 v_feature;         // composited feature: colour or depth
flat out uint v_index;           // the Gaussian's index (id pass)

void main() {
    uint index = order[uint(gl_InstanceID) + u_first];
    Splat s = splats[index];
    v_centre_opacity = vec4(s.centre.xy, 0.0, s.centre.w);
    v_conic = SPLAT_CONIC(s.conic.xyz);
    v_feature = u_mode == 1 ? vec3(s.centre.z) : s.feature.rgb;
    v_index = index;
    if (s.centre.w <= 0.0 || (u_style != STYLE_SPLATS && s.centre.w < u_min_opacity)) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // culled: a degenerate quad outside the clip volume
        return;
    }
    vec2 ax1 = s.axes.xy, ax2 = s.axes.zw;
    if (u_style == STYLE_POINTS) {
        ax1 = vec2(u_point_px + 1.0, 0.0);
        ax2 = vec2(0.0, u_point_px + 1.0);
    } else if (u_style == STYLE_ELLIPSOIDS) {  // the pre-pass scaled the axes by r sigma (see there): use 1.05 sigma
        float r = max(1.002 * sqrt(2.0 * log(255.0 * s.centre.w)), 1e-3);
        ax1 *= 1.05 / r;
        ax2 *= 1.05 / r;
    }
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    vec2 window = s.centre.xy + corner.x * ax1 + corner.y * ax2;
    gl_Position = vec4(window / u_viewport * 2.0 - 1.0, 0.0, 1.0);
}
