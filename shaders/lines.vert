#version 430
// Line segments between points (kNN edges): vertex 2e and 2e + 1 are the two ends of edge e. Positions, edges
// and colours come from storage buffers so that a new pose only rewrites the positions.
layout(std430, binding = 6) readonly buffer PositionBuffer { float positions[]; };  // M x 3
layout(std430, binding = 7) readonly buffer EdgeBuffer { uint edges[]; };          // E x 2
layout(std430, binding = 8) readonly buffer ColourBuffer { uint colours[]; };      // E x RGBA8

uniform mat4 u_view;  // world -> OpenCV camera
uniform mat4 u_proj;  // OpenCV camera -> clip (Camera.opengl_projection)

out vec4 v_colour;

void main() {
    uint e = uint(gl_VertexID) >> 1;
    uint i = edges[2u * e + uint(gl_VertexID & 1)];
    vec3 p = vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    gl_Position = u_proj * (u_view * vec4(p, 1.0));
    v_colour = unpackUnorm4x8(colours[e]);
}
