#version 430
// Composites the premultiplied splat image over a background colour: C + (1 - A) * bg.
// u_flip_y = 1 shows an offscreen image (row 0 = image top) upright on a window.
uniform sampler2D u_image;
uniform vec3 u_background;
uniform int u_flip_y;
uniform float u_colour_scale;  // what the image stores premultiplied colour at (npga_view/rendering/targets.py)
in vec2 v_uv;
out vec4 frag_colour;
void main() {
    vec2 uv = u_flip_y == 1 ? vec2(v_uv.x, 1.0 - v_uv.y) : v_uv;
    vec4 c = texture(u_image, uv);
    frag_colour = vec4(c.rgb / u_colour_scale + (1.0 - c.a) * u_background, 1.0);
}
