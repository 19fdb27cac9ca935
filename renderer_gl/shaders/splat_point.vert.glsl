// One point per Gaussian, expanded into its quad by splat.geom.glsl: the projection runs once per Gaussian
// instead of once per corner, which halves the vertex work on software GL (llvmpipe shades vertices on one thread).
in uint a_index;

out vec2 g_mean;
out vec4 g_axes;
out vec2 g_sigmas;
out vec4 g_color;
out float g_keep;

void main() {
    Splat s;
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);
    g_keep = project_splat(int(a_index), s) ? 1.0 : 0.0;
    g_mean = s.mean;
    g_axes = vec4(s.axis1, s.axis2);
    g_sigmas = s.sigmas;
    g_color = s.color;
}
