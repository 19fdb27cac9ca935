// Overlay lines (camera frustums, paths) in world space, projected with the same pinhole as the splats.
in vec3 a_pos;
in vec4 a_color;
uniform mat4 u_clip_from_world;
out vec4 v_color;
void main() {
    gl_Position = u_clip_from_world * vec4(a_pos, 1.0);
    v_color = a_color;
}
