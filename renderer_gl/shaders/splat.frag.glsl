// Premultiplied alpha, composited back to front with blend (ONE, ONE_MINUS_SRC_ALPHA): onto a target cleared
// to zero this accumulates sum c_i a_i T_i in rgb and 1 - prod(1 - a_i) in alpha, as the training rasterizer.

in vec2 v_d;
flat in vec3 v_conic;
flat in vec4 v_color;

uniform int u_mode;          // 0 colour, 1 depth, 2 outline
uniform float u_outline_sigma;
uniform float u_dither;      // 0, or one step of an 8-bit target (1/255): round stochastically instead of to nearest

out vec4 f_color;

// A hash in [0, 1) of the pixel and the splat: v_d, the pixel's offset from the splat's projected centre, tells
// apart the splats over one pixel (their colours may all be equal), and no texture or state is needed.
float dither_noise() {
    vec3 p = fract(vec3(gl_FragCoord.xy + 0.37 * v_d, dot(v_d, vec2(12.9898, 78.233))) * vec3(0.1031, 0.1030, 0.0973));
    p += dot(p, p.yxz + 33.33);
    return fract((p.x + p.y) * p.z);
}

vec4 quantized_output(vec4 c) {
    // An 8-bit target rounds every blend to the nearest 1/255: a splat adding less than half a step adds nothing,
    // and a thousand faint ones lose their light. Adding (u - 0.5) steps (u uniform) before that rounding makes
    // it floor(x + u), whose mean is x: the noise is unbiased and averages out over the splats of a pixel.
    return u_dither > 0.0 ? c + (dither_noise() - 0.5) * u_dither : c;
}

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
        f_color = quantized_output(vec4(v_color.rgb * alpha, alpha));
        return;
    }
    float alpha = min(ALPHA_MAX, v_color.a * exp(-0.5 * q));
    if (alpha < ALPHA_MIN) discard;
    f_color = quantized_output(vec4(v_color.rgb * alpha, alpha));
}
