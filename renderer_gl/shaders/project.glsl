// Per-Gaussian projection shared by the two ways of drawing the quads (instanced, or one point expanded by a
// geometry shader). Follows the training rasterizer (training/raster/reference.py): EWA Jacobian with the 1.3x
// field-of-view clamp, eps2d low-pass, the same culls, and a quad around the ellipse where
// opacity * exp(-q/2) reaches ALPHA_MIN (opacity-aware, as the CPU rasterizer's screen box).

uniform vec4 u_intr;   // fx, fy, cx, cy in pixels of the target image
uniform vec2 u_size;   // target image width, height in pixels
uniform vec4 u_lim;    // Jacobian clamp limits: +x, -x, +y, -y (in x/z, y/z units)
uniform float u_near;
uniform float u_far;
uniform float u_eps2d;
uniform int u_mode;          // 0 colour, 1 depth, 2 outline
uniform float u_outline_sigma;
uniform vec4 u_tint;         // rgb, strength for selected Gaussians

struct Splat {
    vec2 mean;     // pixels
    vec2 axis1;    // quad half-axes in pixels
    vec2 axis2;
    vec2 sigmas;   // the same half-axes in standard deviations along them (the quad in whitened coordinates)
    vec3 conic;    // inverse 2D covariance (a, b, c)
    vec4 color;    // rgb (or camera depth in .r), opacity
};

vec4 to_clip(vec2 pix) {
    return vec4(2.0 * pix.x / u_size.x - 1.0, 1.0 - 2.0 * pix.y / u_size.y, 0.0, 1.0);
}

bool project_splat(int gid, out Splat s) {
    vec4 t0 = fetch(u_geom, gid * 3);
    vec4 q = fetch(u_geom, gid * 3 + 1);
    vec3 scale = fetch(u_geom, gid * 3 + 2).xyz;
    vec3 mean = t0.xyz;
    float opacity = t0.w;
    uint flags = fetch_flags(gid);
    vec3 p = (u_view * vec4(mean, 1.0)).xyz;
    if (!(p.z >= u_near && p.z <= u_far) || !(opacity >= ALPHA_MIN) || (flags & 2u) != 0u) return false;
    mat3 Mc = mat3(u_view) * quat_to_mat(q) * mat3(scale.x, 0.0, 0.0, 0.0, scale.y, 0.0, 0.0, 0.0, scale.z);
    float fx = u_intr.x, fy = u_intr.y;
    float u = clamp(p.x / p.z, -u_lim.y, u_lim.x);
    float v = clamp(p.y / p.z, -u_lim.w, u_lim.z);
    vec3 j0 = vec3(fx / p.z, 0.0, -fx * u / p.z);
    vec3 j1 = vec3(0.0, fy / p.z, -fy * v / p.z);
    // Rows of T = J Mc, so that Sigma2d = T T^T. det(T T^T) = |t0 x t1|^2 (Cauchy-Binet) has none of the
    // cancellation a*c - b*b suffers in float32 for thin Gaussians, which the reference avoids with float64.
    vec3 r0 = j0 * Mc;
    vec3 r1 = j1 * Mc;
    float a0 = dot(r0, r0), b = dot(r0, r1), c0 = dot(r1, r1);
    vec3 cr = cross(r0, r1);
    float a = a0 + u_eps2d, c = c0 + u_eps2d;
    float det = dot(cr, cr) + u_eps2d * (a0 + c0) + u_eps2d * u_eps2d;
    if (!(det > 0.0)) return false;
    s.conic = vec3(c / det, -b / det, a / det);
    s.mean = vec2(fx * p.x / p.z + u_intr.z, fy * p.y / p.z + u_intr.w);
    float extend = u_mode == 2 ? u_outline_sigma : sqrt(2.0 * log(opacity / ALPHA_MIN));
    // Principal axes of Sigma2d: the quad is the ellipse's bounding rectangle along them.
    float mid = 0.5 * (a + c);
    float rad = sqrt(max(0.25 * (a - c) * (a - c) + b * b, 0.0));
    // l1 l2 = det: the small eigenvalue from it, not from mid - rad, which cancels for thin Gaussians
    float l1 = mid + rad, l2 = max(det / l1, 1e-12);
    vec2 e1 = rad > 0.0 ? normalize(a >= c ? vec2(l1 - c, b) : vec2(b, l1 - a)) : vec2(1.0, 0.0);
    // The margin covers float rounding of the extent; in outline mode a pixel for the line's width.
    float margin = u_mode == 2 ? 1.5 : 0.01;
    s.axis1 = (extend * sqrt(l1) + margin) * e1;
    s.axis2 = (extend * sqrt(l2) + margin) * vec2(-e1.y, e1.x);
    s.sigmas = vec2(extend + margin / sqrt(l1), extend + margin / sqrt(l2));
    if (u_mode == 1) {
        s.color = vec4(p.z, 0.0, 0.0, opacity);
    } else {
        vec3 rgb = sh_color(gid, mean);
        if ((flags & 1u) != 0u) rgb = mix(rgb, u_tint.rgb, u_tint.a);
        s.color = vec4(rgb, opacity);
    }
    return true;
}
