// Gaussian centres as points, drawn in the same back-to-front order as the splats (no depth buffer needed).
in uint a_index;
uniform float u_point_size;
flat out vec4 v_color;

void main() {
    int gid = int(a_index);
    vec4 t0 = fetch(u_geom, gid * 3);
    vec3 p = (u_view * vec4(t0.xyz, 1.0)).xyz;
    uint flags = fetch_flags(gid);
    if (!(p.z >= u_near && p.z <= u_far) || (flags & 2u) != 0u) {
        gl_Position = vec4(-2.0, -2.0, -2.0, 1.0);
        return;
    }
    vec2 pix = vec2(u_intr.x * p.x / p.z + u_intr.z, u_intr.y * p.y / p.z + u_intr.w);
    gl_Position = to_clip(pix);
    gl_PointSize = u_point_size;
    vec3 rgb = sh_color(gid, t0.xyz);
    if ((flags & 1u) != 0u) rgb = mix(rgb, u_tint.rgb, u_tint.a);
    v_color = vec4(rgb, 1.0);
}
