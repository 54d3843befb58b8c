#version 430
// Gaussian falloff with the 3DGS alpha rule; premultiplied output for back-to-front "over" blending
// (blend func ONE, ONE_MINUS_SRC_ALPHA).
#include "splat_common.glsl"

flat in vec4 v_centre_opacity;
flat in vec3 v_conic;
flat in vec3 v_feature;

layout(location = 0) out vec4 frag_colour;

void main() {
    float alpha = splat_alpha(gl_FragCoord.xy - v_centre_opacity.xy, v_conic, v_centre_opacity.w);
    if (alpha < 0.0) discard;
    frag_colour = vec4(v_feature * alpha, alpha);
}
