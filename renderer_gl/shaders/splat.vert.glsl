// One instanced quad per Gaussian, in back-to-front order (a_index): for GPUs, where instancing is cheap.
in vec2 a_corner;      // (+-1, +-1), triangle strip
in uint a_index;       // per instance: the Gaussian drawn

out vec2 v_d;          // pixel offset from the projected mean
flat out vec3 v_conic;
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
    v_conic = s.conic;
    v_color = s.color;
}
