#version 410 core
// OpenGL 4.1 twin of splat_latent.vert: the composited features are latent channels, three per render target
// (the fourth carries alpha). Splats come from u_splats (splat_fetch), the latent features from u_latent:
// Gaussian i's channels are texels i * P .. i * P + P - 1 (P = ceil(H / 4), four channels each) of a texture
// SPLAT_TEXTURE_WIDTH texels wide. NUM_TARGETS is defined by the renderer.
#include "splat_common.glsl"
#include "gl41_splat_fetch.glsl"

uniform sampler2D u_latent;
uniform vec2 u_viewport;
uniform int u_latent_dim;    // H
uniform int u_first_channel; // first latent channel of this pass
uniform uint u_first;        // first sorted position of this draw (a slice of the sorted order)

flat out vec4 v_centre_opacity;
flat out vec3 v_conic;
flat out vec3 v_latent[NUM_TARGETS];

float latent_value(int index, int channel) {
    int t = index * ((u_latent_dim + 3) / 4) + channel / 4;
    vec4 texel = texelFetch(u_latent, ivec2(t % SPLAT_TEXTURE_WIDTH, t / SPLAT_TEXTURE_WIDTH), 0);
    return texel[channel % 4];
}

void main() {
    Splat s = fetch_splat(gl_InstanceID + int(u_first));
    int index = int(s.conic.w + 0.5);
    v_centre_opacity = vec4(s.centre.xy, 0.0, s.centre.w);
    v_conic = s.conic.xyz;
    for (int k = 0; k < NUM_TARGETS; ++k) {
        vec3 values = vec3(0.0);
        for (int j = 0; j < 3; ++j) {
            int channel = u_first_channel + 3 * k + j;
            if (channel < u_latent_dim) values[j] = latent_value(index, channel);
        }
        v_latent[k] = values;
    }
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    vec2 window = s.centre.xy + corner.x * s.axes.xy + corner.y * s.axes.zw;
    gl_Position = vec4(window / u_viewport * 2.0 - 1.0, 0.0, 1.0);
}
