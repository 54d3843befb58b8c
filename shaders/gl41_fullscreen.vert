#version 410 core
// OpenGL 4.1 twin of fullscreen.vert (the same source below this line), for renderer41.py.
// A full-screen triangle for compositing the float splat image onto another framebuffer.
out vec2 v_uv;
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    v_uv = p;
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
