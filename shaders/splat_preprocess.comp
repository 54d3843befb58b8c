#version 430
// Per-camera pre-pass: EWA projection (as 3DGS computeCov2D), SH colour (as 3DGS computeColorFromSH) and the
// oriented quad of every Gaussian. Pixel coordinates follow OpenCV: a pixel centre is at (i + 0.5, j + 0.5).
#include "splat_common.glsl"

layout(local_size_x = 128) in;

layout(std430, binding = 0) readonly buffer GeometryBuffer { vec4 geometry[]; };  // (mean, opacity), quat wxyz, (scale, 0)
layout(std430, binding = 1) readonly buffer SHBuffer { float sh[]; };            // N x K x 3, coefficient-major
layout(std430, binding = 2) writeonly buffer SplatBuffer { Splat splats[]; };
// drawn_count: Gaussians not culled; oversize_count: of those, the ones whose bounding square exceeds u_max_point
// pixels (then the colour pass draws quads instead of points: splat_points.vert). Both zeroed per run.
layout(std430, binding = 5) buffer CounterBuffer { uint drawn_count; uint oversize_count; };

uniform mat4 u_view;       // world -> OpenCV camera
uniform mat4 u_proj;       // OpenCV camera -> clip (Camera.opengl_projection)
uniform vec2 u_viewport;   // width, height in pixels
uniform vec2 u_focal;      // fx, fy
uniform vec2 u_tan_fov;    // tan(fov_x / 2) = W / (2 fx), tan(fov_y / 2)
uniform vec3 u_campos;     // camera centre, world
uniform float u_near;      // Gaussians with depth <= near are culled
uniform uint u_count;
uniform int u_sh_coeffs;   // K = (degree + 1)^2
uniform float u_max_point; // largest point size the GL draws (GL_POINT_SIZE_RANGE)

const float SH_C0 = 0.28209479177387814;
const float SH_C1 = 0.4886025119029199;
const float SH_C2[5] = float[](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                               -1.0925484305920792, 0.5462742152960396);
const float SH_C3[7] = float[](-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                               -0.4570457994644658, 1.445305721320277, -0.5900435899266435);

vec3 sh_coeff(uint base, int k) {
    uint i = base + uint(3 * k);
    return vec3(sh[i], sh[i + 1u], sh[i + 2u]);
}

vec3 sh_colour(uint index, vec3 mean) {
    uint base = index * uint(3 * u_sh_coeffs);
    vec3 result = SH_C0 * sh_coeff(base, 0);
    if (u_sh_coeffs > 1) {
        vec3 dir = normalize(mean - u_campos);
        float x = dir.x, y = dir.y, z = dir.z;
        result += -SH_C1 * y * sh_coeff(base, 1) + SH_C1 * z * sh_coeff(base, 2) - SH_C1 * x * sh_coeff(base, 3);
        if (u_sh_coeffs > 4) {
            float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
            result += SH_C2[0] * xy * sh_coeff(base, 4) + SH_C2[1] * yz * sh_coeff(base, 5)
                    + SH_C2[2] * (2.0 * zz - xx - yy) * sh_coeff(base, 6)
                    + SH_C2[3] * xz * sh_coeff(base, 7) + SH_C2[4] * (xx - yy) * sh_coeff(base, 8);
            if (u_sh_coeffs > 9) {
                result += SH_C3[0] * y * (3.0 * xx - yy) * sh_coeff(base, 9)
                        + SH_C3[1] * xy * z * sh_coeff(base, 10)
                        + SH_C3[2] * y * (4.0 * zz - xx - yy) * sh_coeff(base, 11)
                        + SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * sh_coeff(base, 12)
                        + SH_C3[4] * x * (4.0 * zz - xx - yy) * sh_coeff(base, 13)
                        + SH_C3[5] * z * (xx - yy) * sh_coeff(base, 14)
                        + SH_C3[6] * x * (xx - 3.0 * yy) * sh_coeff(base, 15);
            }
        }
    }
    return max(result + 0.5, vec3(0.0));
}

mat3 quat_to_matrix(vec4 q) {  // q = (w, x, y, z), normalised here as 3DGS does; GLSL matrices are built by column
    q = normalize(q);
    float w = q.x, x = q.y, y = q.z, z = q.w;
    return mat3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
                2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
                2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
}

void cull(uint i) {
    splats[i].centre = vec4(0.0);
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= u_count) return;
    vec4 g0 = geometry[3u * i];
    vec3 mean = g0.xyz;
    float opacity = g0.w;
    vec3 t = (u_view * vec4(mean, 1.0)).xyz;
    if (!(t.z > u_near) || opacity < MIN_ALPHA) { cull(i); return; }

    // 3D covariance R S S^T R^T
    mat3 m = quat_to_matrix(geometry[3u * i + 1u]) * mat3(vec3(geometry[3u * i + 2u].x, 0.0, 0.0),
                                                         vec3(0.0, geometry[3u * i + 2u].y, 0.0),
                                                         vec3(0.0, 0.0, geometry[3u * i + 2u].z));
    mat3 cov3d = m * transpose(m);

    // EWA: Jacobian of the perspective projection at t, with t.xy/t.z clamped to 1.3 tan(fov/2) as in 3DGS
    vec2 lim = 1.3 * u_tan_fov;
    vec2 txy = clamp(t.xy / t.z, -lim, lim) * t.z;
    float inv_z = 1.0 / t.z;
    // rows of J: (fx/z, 0, -fx x/z^2), (0, fy/z, -fy y/z^2); GLSL mat3x2 is 3 columns of vec2
    mat3x2 jac = mat3x2(vec2(u_focal.x * inv_z, 0.0), vec2(0.0, u_focal.y * inv_z),
                        vec2(-u_focal.x * txy.x * inv_z * inv_z, -u_focal.y * txy.y * inv_z * inv_z));
    mat3x2 tm = jac * mat3(u_view);
    mat2 cov2d = tm * cov3d * transpose(tm);
    float a = cov2d[0][0] + 0.3, b = cov2d[1][0], c = cov2d[1][1] + 0.3;
    float det = a * c - b * b;
    if (!(det > 0.0)) { cull(i); return; }

    // window coordinates of the centre: x = u; y = v (offscreen) or H - v (flipped projection)
    vec4 clip = u_proj * vec4(t, 1.0);
    vec2 centre = (clip.xy / clip.w * 0.5 + 0.5) * u_viewport;
    float flip = sign(u_proj[1][1]);  // +1: window y = v, -1: window y = H - v
    b *= flip;

    // quad: eigenvectors of the covariance scaled by sqrt(eigenvalue) and by the radius r where
    // opacity * exp(-r^2 / 2) = 1/255 (alpha below 1/255 is discarded anyway; r <= 3.33 since opacity <= 1),
    // widened by 0.2 % so that rounding never clips a pixel the fragment shader would keep
    float r = 1.002 * sqrt(2.0 * log(255.0 * opacity));
    float mid = 0.5 * (a + c);
    float disc = sqrt(max(0.25 * (a - c) * (a - c) + b * b, 0.0));
    float l1 = mid + disc;
    float l2 = det / l1;
    vec2 e1 = (a >= c) ? vec2(l1 - c, b) : vec2(b, l1 - a);
    float len = length(e1);
    e1 = len > 0.0 ? e1 / len : vec2(1.0, 0.0);
    vec2 ax1 = e1 * (sqrt(l1) * r);
    vec2 ax2 = vec2(-e1.y, e1.x) * (sqrt(l2) * r);

    // off-screen: the bounding box of the ellipse misses the viewport
    vec2 half_box = r * sqrt(vec2(a, c));
    if (any(lessThan(centre + half_box, vec2(0.0))) || any(greaterThan(centre - half_box, u_viewport))) {
        cull(i);
        return;
    }
    splats[i].centre = vec4(centre, t.z, opacity);
    splats[i].axes = vec4(ax1, ax2);
    splats[i].conic = vec4(c / det, -b / det, a / det, 0.0);
    float side = point_side(half_box);
    splats[i].feature = vec4(sh_colour(i, mean), side);
    atomicAdd(drawn_count, 1u);
    if (side > u_max_point) atomicAdd(oversize_count, 1u);
}
