#version 410 core
// OpenGL 4.1 twin of splat_points.vert: the colour pass as one GL point per kept splat (when every splat's
// bounding square fits the GL's point size range), clipped by its centre inside a viewport widened by u_guard.
#include "splat_common.glsl"
#include "gl41_splat_fetch.glsl"

uniform vec2 u_viewport;
uniform uint u_first;   // first sorted position of this draw
uniform int u_mode;     // 0: colour, 1: depth
uniform float u_guard;  // guard band in pixels (half the largest point size)

flat out vec4 v_centre_opacity;
flat out vec3 v_conic;
flat out vec3 v_feature;
flat out uint v_index;

void main() {
    Splat s = fetch_splat(gl_VertexID + int(u_first));
    v_centre_opacity = vec4(s.centre.xy, 0.0, s.centre.w);
    v_conic = SPLAT_CONIC(s.conic.xyz);
    v_feature = u_mode == 1 ? vec3(s.centre.z) : s.feature.rgb;
    v_index = uint(s.conic.w + 0.5);
    gl_PointSize = s.feature.w;  // point_side (pre-pass)
    vec2 extended = u_viewport + 2.0 * u_guard;
    gl_Position = vec4((s.centre.xy + u_guard) / extended * 2.0 - 1.0, 0.0, 1.0);
}
