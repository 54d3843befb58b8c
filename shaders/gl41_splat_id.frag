#version 410 core
// OpenGL 4.1 twin of splat_id.frag (the same source below this line), for renderer41.py.
// Id pass: writes index + 1 of the Gaussian into an R32UI target where its alpha (in the current style) reaches
// u_threshold. Quads come back to front without blending, so the front-most such Gaussian (by centre depth,
// the order of the colour pass) is what stays in a pixel; 0 means none.
#include "splat_common.glsl"

flat in vec4 v_centre_opacity;
flat in vec3 v_conic;
flat in uint v_index;

uniform int u_style;
uniform float u_point_px;
uniform float u_threshold;

layout(location = 0) out uint frag_id;

void main() {
    float shade;
    float alpha = style_alpha(gl_FragCoord.xy - v_centre_opacity.xy, v_conic, v_centre_opacity.w, u_style,
                              u_point_px, shade);
    if (alpha < u_threshold) discard;
    frag_id = v_index + 1u;
}
