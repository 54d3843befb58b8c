#version 410 core
// OpenGL 4.1 twin of lines.frag (the same source below this line), for renderer41.py.
// Premultiplied line colour, blended "over" the splat image.
in vec4 v_colour;
uniform float u_colour_scale;  // what the target stores premultiplied colour at (npga_view/rendering/targets.py)
layout(location = 0) out vec4 frag_colour;
void main() {
    frag_colour = vec4(v_colour.rgb * (v_colour.a * u_colour_scale), v_colour.a);
}
