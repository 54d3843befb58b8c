#version 410 core
// OpenGL 4.1 twin of splat.frag (the same source below this line), for renderer41.py.
// Gaussian falloff with the 3DGS alpha rule (or a geometry style); premultiplied output for back-to-front
// "over" blending (blend func ONE, ONE_MINUS_SRC_ALPHA).
#include "splat_common.glsl"

flat in vec4 v_centre_opacity;
flat in vec3 v_conic;
flat in vec3 v_feature;

uniform int u_style;
uniform float u_point_px;

layout(location = 0) out vec4 frag_colour;

void main() {
    float shade;
    float alpha = style_alpha(gl_FragCoord.xy - v_centre_opacity.xy, v_conic, v_centre_opacity.w, u_style,
                              u_point_px, shade);
    if (alpha < 0.0) discard;
    frag_colour = vec4(v_feature * shade * alpha, alpha);
}
