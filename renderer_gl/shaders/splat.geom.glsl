// One triangle per Gaussian, around the ellipse where its alpha reaches ALPHA_MIN: the equilateral triangle
// circumscribing the unit circle, mapped onto the ellipse's axes. On software GL (where this path is used) a
// primitive costs about as much as 40 of its pixels: one triangle of 5.2 r^2 drew a frame of 100k splats at
// 1280x720 in 7 % less CPU time than the two triangles of the 4 r^2 bounding quad (docs/performance.md).
layout(points) in;
layout(triangle_strip, max_vertices = 3) out;

in vec2 g_mean[];
in vec4 g_axes[];
in vec2 g_sigmas[];
in vec4 g_color[];
in float g_keep[];
uniform vec2 u_size;

out vec2 v_d;
out vec2 v_w;
flat out vec4 v_color;

const vec2 CORNERS[3] = vec2[3](vec2(0.0, 2.0), vec2(-1.7320508075688772, -1.0), vec2(1.7320508075688772, -1.0));

void main() {
    if (g_keep[0] == 0.0) return;
    for (int k = 0; k < 3; ++k) {
        vec2 corner = CORNERS[k];
        vec2 offset = corner.x * g_axes[0].xy + corner.y * g_axes[0].zw;
        vec2 pix = g_mean[0] + offset;
        gl_Position = vec4(2.0 * pix.x / u_size.x - 1.0, 1.0 - 2.0 * pix.y / u_size.y, 0.0, 1.0);
        v_d = offset;
        v_w = corner * g_sigmas[0] * WHITE_SCALE;
        v_color = g_color[0];
        EmitVertex();
    }
    EndPrimitive();
}
