// A rectangle of the target's viewport; v_uv runs 0..1 bottom to top as GL textures do.
in vec2 a_corner;
out vec2 v_uv;
void main() {
    v_uv = 0.5 * (a_corner + 1.0);
    gl_Position = vec4(a_corner, 0.0, 1.0);
}
