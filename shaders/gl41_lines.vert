#version 410 core
// OpenGL 4.1 twin of lines.vert: the two ends of every segment as vertex attributes (gathered on the CPU from
// the positions and edges) instead of storage buffers; one colour per segment, repeated at both ends.
in vec3 in_position;
in vec4 in_colour;

uniform mat4 u_view;  // world -> OpenCV camera
uniform mat4 u_proj;  // OpenCV camera -> clip (Camera.opengl_projection)

out vec4 v_colour;

void main() {
    gl_Position = u_proj * (u_view * vec4(in_position, 1.0));
    v_colour = in_colour;
}
