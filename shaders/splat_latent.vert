#version 430
// Latent pass: like splat.vert, but the composited features are latent channels, three per render target
// (the fourth channel of every target carries alpha, which the blend equation needs).
// NUM_TARGETS is defined by the renderer.
#include "splat_common.glsl"

layout(std430, binding = 2) readonly buffer SplatBuffer { Splat splats[]; };
layout(std430, binding = 3) readonly buffer OrderBuffer { uint order[]; };
layout(std430, binding = 4) readonly buffer LatentBuffer { float latent[]; };  // N x H

uniform vec2 u_viewport;
uniform int u_latent_dim;    // H
uniform int u_first_channel; // first latent channel of this pass
uniform uint u_first;        // first sorted position of this draw (a slice of the sorted order)

flat out vec4 v_centre_opacity;
flat out vec3 v_conic;
flat out vec3 v_latent[NUM_TARGETS];

void main() {
    uint index = order[uint(gl_InstanceID) + u_first];
    Splat s = splats[index];
    v_centre_opacity = vec4(s.centre.xy, 0.0, s.centre.w);
    v_conic = s.conic.xyz;
    uint base = index * uint(u_latent_dim);
    for (int k = 0; k < NUM_TARGETS; ++k) {
        vec3 values = vec3(0.0);
        for (int j = 0; j < 3; ++j) {
            int channel = u_first_channel + 3 * k + j;
            if (channel < u_latent_dim) values[j] = latent[base + uint(channel)];
        }
        v_latent[k] = values;
    }
    if (s.centre.w <= 0.0) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        return;
    }
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
    vec2 window = s.centre.xy + corner.x * s.axes.xy + corner.y * s.axes.zw;
    gl_Position = vec4(window / u_viewport * 2.0 - 1.0, 0.0, 1.0);
}
