// Shared definitions of the splat passes (inserted by the renderer's `#include` resolver).

// The conic as the colour pass of the "splats" style takes it (SPLATS_ONLY in splat.frag): scaled so that the
// exponent is exp2's, -0.5 log2(e) (a, 2b, c); llvmpipe's exp is exp2 of a product, and folding the factors into
// the per-splat conic made the demo's colour pass 2-4 % faster (docs/PERFORMANCE.md). Other passes take it as is.
#ifdef SPLATS_ONLY
#define SPLAT_CONIC(k) ((k) * vec3(-0.7213475204444817, -1.4426950408889634, -0.7213475204444817))
#else
#define SPLAT_CONIC(k) (k)
#endif

// Gaussians with alpha below this are skipped, as in 3DGS.
const float MIN_ALPHA = 1.0 / 255.0;
// Maximum alpha of one Gaussian, as in 3DGS.
const float MAX_ALPHA = 0.99;

// One projected Gaussian, written by splat_preprocess.comp once per camera, read by the draw passes.
struct Splat {
    vec4 centre;   // xy: centre in window pixels; z: camera-space depth; w: opacity (0 = culled)
    vec4 axes;     // xy, zw: the two half-axes of the quad in window pixels (eigenvectors * sqrt(eigenvalue) * r)
    vec4 conic;    // xyz: inverse 2D covariance (a, b, c) in window pixels; w unused
    vec4 feature;  // rgb: colour from SH; w: side of the GL point that holds the splat (point_side)
};

// alpha of a Gaussian at offset d (window pixels) from its centre, as 3DGS renderCUDA (-1 when skipped)
float splat_alpha(vec2 d, vec3 conic, float opacity) {
    float power = -0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) - conic.y * d.x * d.y;
    if (power > 0.0) return -1.0;
    float alpha = min(MAX_ALPHA, opacity * exp(power));
    return alpha < MIN_ALPHA ? -1.0 : alpha;
}


// Draw styles (uniform u_style of the draw passes): the 3DGS splat; points: opaque discs of a fixed radius in
// pixels; ellipsoids: the 1-sigma ellipse of the projected covariance, opaque, shaded like a lit ellipsoid
// seen along the view direction.
const int STYLE_SPLATS = 0;
const int STYLE_POINTS = 1;
const int STYLE_ELLIPSOIDS = 2;

// alpha of a fragment at offset d in a style (-1 when outside), and a shading factor for its colour
float style_alpha(vec2 d, vec3 conic, float opacity, int style, float point_px, out float shade) {
    shade = 1.0;
    if (style == STYLE_POINTS) return dot(d, d) <= point_px * point_px ? 1.0 : -1.0;
    if (style == STYLE_ELLIPSOIDS) {
        float q = conic.x * d.x * d.x + 2.0 * conic.y * d.x * d.y + conic.z * d.y * d.y;
        if (q > 1.0) return -1.0;
        shade = 0.3 + 0.7 * sqrt(1.0 - q);
        return 1.0;
    }
    return splat_alpha(d, conic, opacity);
}

// Side of the screen-aligned square that holds a splat's ellipse at the alpha = 1/255 radius r (its bounding box
// has the half-extents r sqrt(cov_xx), r sqrt(cov_yy)), widened by POINT_MARGIN: drawn as a GL point of this
// size, a splat keeps the same fragments as its quad (every other pixel fails the 1/255 alpha test). The margin
// only has to outlast rounding (a window position is snapped to 1/256 pixel, the NDC round trip costs ~1e-4),
// since a kept pixel centre lies inside the box by r's 0.2 % widening; a whole pixel, as before, made the demo's
// squares 8 % larger in area. The box of the ellipse, not of its quad: up to half the area for a splat turned
// 45 degrees.
const float POINT_MARGIN = 0.05;
float point_side(vec2 half_box) {
    return 2.0 * max(half_box.x, half_box.y) + POINT_MARGIN;
}
