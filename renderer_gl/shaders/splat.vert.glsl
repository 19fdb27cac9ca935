// One instanced quad per Gaussian, in back-to-front order (a_index). Projection follows the training
// rasterizer (training/raster/reference.py): EWA Jacobian with the 1.3x field-of-view clamp, eps2d low-pass,
// the same culls, and a quad around the ellipse where opacity * exp(-q/2) reaches ALPHA_MIN (opacity-aware).

in vec2 a_corner;      // (+-1, +-1), triangle strip
in uint a_index;       // per instance: the Gaussian drawn

uniform vec4 u_intr;   // fx, fy, cx, cy in pixels of the target image
uniform vec2 u_size;   // target image width, height in pixels
uniform vec4 u_lim;    // Jacobian clamp limits: +x, -x, +y, -y (in x/z, y/z units)
uniform float u_near;
uniform float u_far;
uniform float u_eps2d;
uniform int u_mode;          // 0 colour, 1 depth, 2 outline
uniform float u_outline_sigma;
uniform vec4 u_tint;         // rgb, strength for selected Gaussians

out vec2 v_d;                // pixel offset from the projected mean
flat out vec3 v_conic;       // inverse 2D covariance (a, b, c)
flat out vec4 v_color;       // rgb (or depth in .r), opacity

const vec4 CULLED = vec4(-2.0, -2.0, -2.0, 1.0);

void main() {
    int gid = int(a_index);
    vec4 t0 = fetch(u_geom, gid * 3);
    vec4 q = fetch(u_geom, gid * 3 + 1);
    vec3 scale = fetch(u_geom, gid * 3 + 2).xyz;
    vec3 mean = t0.xyz;
    float opacity = t0.w;
    uint flags = fetch_flags(gid);
    vec3 p = (u_view * vec4(mean, 1.0)).xyz;
    if (!(p.z >= u_near && p.z <= u_far) || !(opacity >= ALPHA_MIN) || (flags & 2u) != 0u) {
        gl_Position = CULLED;
        return;
    }
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
    if (!(det > 0.0)) {
        gl_Position = CULLED;
        return;
    }
    vec3 conic = vec3(c / det, -b / det, a / det);
    vec2 mean2d = vec2(fx * p.x / p.z + u_intr.z, fy * p.y / p.z + u_intr.w);

    float extend = sqrt(2.0 * log(opacity / ALPHA_MIN));
    if (u_mode == 2) extend = u_outline_sigma;
    // Principal axes of Sigma2d: the quad is the ellipse's bounding rectangle along them.
    float mid = 0.5 * (a + c);
    float rad = sqrt(max(0.25 * (a - c) * (a - c) + b * b, 0.0));
    float l1 = mid + rad, l2 = max(mid - rad, 1e-12);
    vec2 e1 = rad > 0.0 ? normalize(a >= c ? vec2(l1 - c, b) : vec2(b, l1 - a)) : vec2(1.0, 0.0);
    vec2 e2 = vec2(-e1.y, e1.x);
    // The margin covers float rounding of the extent; in outline mode a pixel for the line's width.
    float margin = u_mode == 2 ? 1.5 : 0.01;
    vec2 offset = a_corner.x * (extend * sqrt(l1) + margin) * e1 + a_corner.y * (extend * sqrt(l2) + margin) * e2;
    vec2 pix = mean2d + offset;
    gl_Position = vec4(2.0 * pix.x / u_size.x - 1.0, 1.0 - 2.0 * pix.y / u_size.y, 0.0, 1.0);
    v_d = offset;
    v_conic = conic;
    if (u_mode == 1) {
        v_color = vec4(p.z, 0.0, 0.0, opacity);
    } else {
        vec3 rgb = sh_color(gid, mean);
        if ((flags & 1u) != 0u) rgb = mix(rgb, u_tint.rgb, u_tint.a);
        v_color = vec4(rgb, opacity);
    }
}
