// Shared by the splat and point programs: fetching a Gaussian's parameters from the data textures and
// evaluating its colour. Defines (ALPHA_MIN, ALPHA_MAX, SH_C*) are prepended by renderer_gl/shader_source.py.

uniform sampler2D u_geom;   // 3 RGBA32F texels per Gaussian: (mean, opacity), (quat wxyz), (scale, 0)
uniform sampler2D u_sh;     // u_sh_stride texels per Gaussian: coefficients flattened k-major, rgb per k
uniform usampler2D u_flags; // 1 R8UI texel per Gaussian: bit 0 selected, bit 1 hidden
uniform int u_sh_stride;
uniform int u_sh_degree;    // the degree evaluated (min of the model's and the caller's maximum)
uniform mat4 u_view;        // world to camera, OpenCV axes (z forward, y down)
uniform vec3 u_campos;

ivec2 texel_at(sampler2D tex, int i) {
    int w = textureSize(tex, 0).x;
    return ivec2(i % w, i / w);
}

vec4 fetch(sampler2D tex, int i) {
    return texelFetch(tex, texel_at(tex, i), 0);
}

uint fetch_flags(int gid) {
    int w = textureSize(u_flags, 0).x;
    return texelFetch(u_flags, ivec2(gid % w, gid / w), 0).r;
}

mat3 quat_to_mat(vec4 q) {
    q = q / max(length(q), 1e-12);
    float w = q.x, x = q.y, y = q.z, z = q.w;
    // GLSL matrices are column-major: each vec3 below is a column of the rotation.
    return mat3(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
        2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
        2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
}

vec3 sh_color(int gid, vec3 mean) {
    int nk = (u_sh_degree + 1) * (u_sh_degree + 1);
    float c[48];
    int base = gid * u_sh_stride;
    int ntex = (nk * 3 + 3) / 4;
    for (int t = 0; t < ntex; ++t) {
        vec4 v = fetch(u_sh, base + t);
        c[4 * t] = v.x; c[4 * t + 1] = v.y; c[4 * t + 2] = v.z; c[4 * t + 3] = v.w;
    }
    #define COEF(k) vec3(c[3 * (k)], c[3 * (k) + 1], c[3 * (k) + 2])
    vec3 rgb = SH_C0 * COEF(0);
    if (u_sh_degree >= 1) {
        vec3 d = mean - u_campos;
        d = d / max(length(d), 1e-12);
        float x = d.x, y = d.y, z = d.z;
        rgb += -SH_C1 * y * COEF(1) + SH_C1 * z * COEF(2) - SH_C1 * x * COEF(3);
        if (u_sh_degree >= 2) {
            float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
            rgb += SH_C2_0 * xy * COEF(4) + SH_C2_1 * yz * COEF(5) + SH_C2_2 * (2.0 * zz - xx - yy) * COEF(6)
                 + SH_C2_3 * xz * COEF(7) + SH_C2_4 * (xx - yy) * COEF(8);
            if (u_sh_degree >= 3) {
                rgb += SH_C3_0 * y * (3.0 * xx - yy) * COEF(9) + SH_C3_1 * xy * z * COEF(10)
                     + SH_C3_2 * y * (4.0 * zz - xx - yy) * COEF(11)
                     + SH_C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * COEF(12)
                     + SH_C3_4 * x * (4.0 * zz - xx - yy) * COEF(13) + SH_C3_5 * z * (xx - yy) * COEF(14)
                     + SH_C3_6 * x * (xx - 3.0 * yy) * COEF(15);
            }
        }
    }
    #undef COEF
    return max(rgb + 0.5, vec3(0.0));
}
