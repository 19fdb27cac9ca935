layout(points) in;
layout(triangle_strip, max_vertices = 4) out;

in vec2 g_mean[];
in vec4 g_axes[];
in vec3 g_conic[];
in vec4 g_color[];
in float g_keep[];
uniform vec2 u_size;

out vec2 v_d;
flat out vec3 v_conic;
flat out vec4 v_color;

void main() {
    if (g_keep[0] == 0.0) return;
    for (int k = 0; k < 4; ++k) {
        vec2 offset = ((k & 1) == 0 ? -1.0 : 1.0) * g_axes[0].xy + ((k & 2) == 0 ? -1.0 : 1.0) * g_axes[0].zw;
        vec2 pix = g_mean[0] + offset;
        gl_Position = vec4(2.0 * pix.x / u_size.x - 1.0, 1.0 - 2.0 * pix.y / u_size.y, 0.0, 1.0);
        v_d = offset;
        v_conic = g_conic[0];
        v_color = g_color[0];
        EmitVertex();
    }
    EndPrimitive();
}
