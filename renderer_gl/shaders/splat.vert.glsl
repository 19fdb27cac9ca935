// One instanced quad per Gaussian, in back-to-front order (a_index): for GPUs, where instancing is cheap.
in vec2 a_corner;      // (+-1, +-1), triangle strip
in uint a_index;       // per instance: the Gaussian drawn

out vec2 v_d;          // pixel offset from the projected mean
out vec2 v_w;          // the offset whitened (q = d^T Sigma^-1 d = |w|^2), times sqrt(log2(e) / 2)
flat out vec4 v_color;

void main() {
    Splat s;
    if (!project_splat(int(a_index), s)) {
        gl_Position = vec4(-2.0, -2.0, -2.0, 1.0);  // all four corners at one point outside: nothing drawn
        return;
    }
    vec2 offset = a_corner.x * s.axis1 + a_corner.y * s.axis2;
    gl_Position = to_clip(s.mean + offset);
    v_d = offset;
    v_w = a_corner * s.sigmas * WHITE_SCALE;
    v_color = s.color;
}
