#version 430
// Gaussian falloff with the 3DGS alpha rule (or a geometry style); premultiplied output for back-to-front
// "over" blending (blend func ONE, ONE_MINUS_SRC_ALPHA).
#include "splat_common.glsl"

flat in vec4 v_centre_opacity;
flat in vec3 v_conic;
flat in vec3 v_feature;

uniform int u_style;
uniform float u_point_px;
uniform float u_colour_scale;  // what the target stores premultiplied colour at (npga_view/rendering/targets.py)

layout(location = 0) out vec4 frag_colour;

void main() {
#ifdef SPLATS_ONLY
    // The colour pass of the "splats" style (its usual program): splat_alpha without the style branches, and a
    // fragment below 1/255 blended with alpha 0 instead of discarded (the same pixels: premultiplied zero adds
    // nothing in either blend order). Both measured ~7 % faster each on llvmpipe (docs/PERFORMANCE.md). The conic
    // comes scaled for exp2 (SPLAT_CONIC): p2 is 3DGS's power times log2(e).
    vec2 d = gl_FragCoord.xy - v_centre_opacity.xy;
    float p2 = v_conic.x * d.x * d.x + v_conic.z * d.y * d.y + v_conic.y * d.x * d.y;
    float alpha = min(MAX_ALPHA, v_centre_opacity.w * exp2(p2));
    alpha = (p2 > 0.0 || alpha < MIN_ALPHA) ? 0.0 : alpha;
    frag_colour = vec4(v_feature * (alpha * u_colour_scale), alpha);
#else
    float shade;
    float alpha = style_alpha(gl_FragCoord.xy - v_centre_opacity.xy, v_conic, v_centre_opacity.w, u_style,
                              u_point_px, shade);
    if (alpha < 0.0) discard;
    frag_colour = vec4(v_feature * (shade * alpha * u_colour_scale), alpha);
#endif
}
