// The OpenGL 4.1 path (renderer41.py) has no storage buffers: its CPU pre-pass writes the kept splats in draw
// order (back to front) into the RGBA32F texture u_splats, four texels per splat (the fields of `Splat`, with
// the Gaussian's index in conic.w), SPLAT_TEXTURE_WIDTH texels per row.
const int SPLAT_TEXTURE_WIDTH = 4096;

uniform sampler2D u_splats;

Splat fetch_splat(int position) {
    int t = 4 * position;
    ivec2 c = ivec2(t % SPLAT_TEXTURE_WIDTH, t / SPLAT_TEXTURE_WIDTH);
    Splat s;
    s.centre = texelFetch(u_splats, c, 0);
    s.axes = texelFetch(u_splats, c + ivec2(1, 0), 0);
    s.conic = texelFetch(u_splats, c + ivec2(2, 0), 0);
    s.feature = texelFetch(u_splats, c + ivec2(3, 0), 0);
    return s;
}
