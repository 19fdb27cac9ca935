// Premultiplied alpha, composited back to front with blend (ONE, ONE_MINUS_SRC_ALPHA): onto a target cleared
// to zero this accumulates sum c_i a_i T_i in rgb and 1 - prod(1 - a_i) in alpha, as the training rasterizer.

in vec2 v_d;
flat in vec3 v_conic;
flat in vec4 v_color;

uniform int u_mode;          // 0 colour, 1 depth, 2 outline
uniform float u_outline_sigma;

out vec4 f_color;

void main() {
    vec2 d = v_d;
    float q = v_conic.x * d.x * d.x + v_conic.z * d.y * d.y + 2.0 * v_conic.y * d.x * d.y;
    if (u_mode == 2) {
        // One pixel wide line on the outline_sigma contour of the projected Gaussian.
        float s = sqrt(max(q, 0.0));
        float w = max(fwidth(s), 1e-6);
        float cover = 1.0 - clamp(abs(s - u_outline_sigma) / w, 0.0, 1.0);
        float alpha = cover * clamp(v_color.a, 0.25, 1.0);
        if (alpha < ALPHA_MIN) discard;
        f_color = vec4(v_color.rgb * alpha, alpha);
        return;
    }
    float alpha = min(ALPHA_MAX, v_color.a * exp(-0.5 * q));
    if (alpha < ALPHA_MIN) discard;
    f_color = vec4(v_color.rgb * alpha, alpha);
}
