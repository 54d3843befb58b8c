#version 430
// The colour pass as GL points: one vertex per Gaussian instead of an instanced quad of four (the vertex work
// is what bounds llvmpipe), used when every splat's bounding square fits the GL's point size range. The
// fragment shader (splat.frag) is the quad path's, so the kept fragments and their order are the same.
// Points are clipped by their centre: the viewport is widened by u_guard pixels on every side (the renderer
// sets glViewport accordingly), so a point whose square reaches into the image is never dropped.
#include "splat_common.glsl"

layout(std430, binding = 2) readonly buffer SplatBuffer { Splat splats[]; };
layout(std430, binding = 3) readonly buffer OrderBuffer { uint order[]; };

uniform vec2 u_viewport;
uniform uint u_first;   // first sorted position of this draw
uniform int u_mode;     // 0: colour, 1: depth
uniform float u_guard;  // guard band in pixels (half the largest point size)

flat out vec4 v_centre_opacity;
flat out vec3 v_conic;
flat out vec3 v_feature;
flat out uint v_index;

void main() {
    uint index = order[uint(gl_VertexID) + u_first];
    Splat s = splats[index];
    v_centre_opacity = vec4(s.centre.xy, 0.0, s.centre.w);
    v_conic = SPLAT_CONIC(s.conic.xyz);
    v_feature = u_mode == 1 ? vec3(s.centre.z) : s.feature.rgb;
    v_index = index;
    if (s.centre.w <= 0.0) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // culled
        gl_PointSize = 1.0;
        return;
    }
    gl_PointSize = s.feature.w;  // point_side (pre-pass)
    vec2 extended = u_viewport + 2.0 * u_guard;
    gl_Position = vec4((s.centre.xy + u_guard) / extended * 2.0 - 1.0, 0.0, 1.0);
}
