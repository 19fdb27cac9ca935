// Premultiplied alpha, composited back to front with blend (ONE, ONE_MINUS_SRC_ALPHA): onto a target cleared
// to zero this accumulates sum c_i a_i T_i in rgb and 1 - prod(1 - a_i) in alpha, as the training rasterizer.

// v_w: the pixel's offset from the splat's centre whitened by the 2D covariance and scaled, so that the exponent
// -q/2 = -|v_w|^2 / log2(e) and alpha = opacity * exp2(-|v_w|^2). It is linear in the pixel position, so its
// interpolation across the quad is exact: the fragment pays one dot product instead of the conic's quadratic form.
in vec2 v_w;
flat in vec4 v_color;

uniform float u_outline_sigma;  // OUTLINE (the program of render mode "ellipsoids")

out vec4 f_color;

#ifdef DITHER
// Compiled only into the program of an 8-bit target that dithers: llvmpipe evaluates both sides of a select, so a
// run-time switch made every other target pay for the hash at every fragment.
in vec2 v_d;
uniform float u_dither;      // one step of an 8-bit target (1/255): round stochastically instead of to nearest

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
    return c + (dither_noise() - 0.5) * u_dither;
}
#else
vec4 quantized_output(vec4 c) {
    return c;
}
#endif

void main() {
    float e = dot(v_w, v_w);  // = q log2(e) / 2
#ifdef OUTLINE
    // One pixel wide line on the outline_sigma contour of the projected Gaussian.
    float s = sqrt(e * (2.0 / LOG2E));  // sqrt(q): the distance from the centre in standard deviations
    float w = max(fwidth(s), 1e-6);
    float cover = 1.0 - clamp(abs(s - u_outline_sigma) / w, 0.0, 1.0);
    float alpha = cover * clamp(v_color.a, 0.25, 1.0);
#else
    float alpha = min(ALPHA_MAX, v_color.a * exp2(-e));
#endif
    if (alpha < ALPHA_MIN) discard;
    f_color = quantized_output(vec4(v_color.rgb * alpha, alpha));
}
