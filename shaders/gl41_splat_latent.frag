#version 410 core
// OpenGL 4.1 twin of splat_latent.frag (the same source below this line), for renderer41.py.
// Latent pass fragment shader: three latent channels and alpha per target, premultiplied.
#include "splat_common.glsl"

flat in vec4 v_centre_opacity;
flat in vec3 v_conic;
flat in vec3 v_latent[NUM_TARGETS];

layout(location = 0) out vec4 frag_out[NUM_TARGETS];

void main() {
    float alpha = splat_alpha(gl_FragCoord.xy - v_centre_opacity.xy, v_conic, v_centre_opacity.w);
    if (alpha < 0.0) discard;
    for (int k = 0; k < NUM_TARGETS; ++k) frag_out[k] = vec4(v_latent[k] * alpha, alpha);
}
