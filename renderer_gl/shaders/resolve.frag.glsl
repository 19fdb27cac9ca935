// Turns the float accumulation target into the picture of a render mode, over the background, with the
// ground-truth photo and the split divider on top.
in vec2 v_uv;
uniform sampler2D u_accum;   // rgb = sum f_i a_i T_i (f = colour, or depth in .r), a = accumulated alpha
uniform sampler2D u_photo;   // stored top row first, so sampled with v flipped
uniform vec3 u_background;
uniform vec2 u_depth_range;  // near, far of the colour map
uniform float u_photo_alpha; // PHOTO_BLEND: the photo's blend weight
uniform float u_split;       // SPLIT: divider position in 0..1 of the width
uniform vec4 u_divider_color;
uniform vec2 u_target_size;  // viewport size in pixels (for a one-pixel divider)
out vec4 f_color;

vec3 depth_colormap(float t) {
    // Dark violet (near) through red and orange to pale yellow (far): monotonic in lightness, so a grey
    // print still reads as depth.
    const vec3 k0 = vec3(0.05, 0.02, 0.20);
    const vec3 k1 = vec3(0.45, 0.05, 0.50);
    const vec3 k2 = vec3(0.85, 0.25, 0.25);
    const vec3 k3 = vec3(0.98, 0.62, 0.10);
    const vec3 k4 = vec3(0.99, 0.98, 0.70);
    t = clamp(t, 0.0, 1.0) * 4.0;
    if (t < 1.0) return mix(k0, k1, t);
    if (t < 2.0) return mix(k1, k2, t - 1.0);
    if (t < 3.0) return mix(k2, k3, t - 2.0);
    return mix(k3, k4, t - 3.0);
}

// Compiled per (RESOLVE_MODE, PHOTO_BLEND, SPLIT) (renderer.py): llvmpipe runs every branch on a uniform for
// every pixel, so one program with all of them cost an empty 1280x720 frame half its time.
void main() {
#if RESOLVE_MODE == 3
    f_color = vec4(texture(u_photo, vec2(v_uv.x, 1.0 - v_uv.y)).rgb, 1.0);
#else
    vec4 acc = texture(u_accum, v_uv);
    float alpha = clamp(acc.a, 0.0, 1.0);
#if RESOLVE_MODE == 1
    float depth = acc.r / max(acc.a, 1e-10);
    float t = (depth - u_depth_range.x) / max(u_depth_range.y - u_depth_range.x, 1e-12);
    vec3 rgb = mix(u_background, depth_colormap(t), alpha);
#elif RESOLVE_MODE == 2
    vec3 rgb = vec3(alpha);
#else
    vec3 rgb = acc.rgb + (1.0 - alpha) * u_background;
#endif
#ifdef PHOTO_BLEND
    rgb = mix(rgb, texture(u_photo, vec2(v_uv.x, 1.0 - v_uv.y)).rgb, u_photo_alpha);
#endif
#ifdef SPLIT
    float px = v_uv.x * u_target_size.x;
    if (abs(px - u_split * u_target_size.x) <= 1.0) rgb = mix(rgb, u_divider_color.rgb, u_divider_color.a);
#endif
    f_color = vec4(clamp(rgb, 0.0, 1.0), 1.0);
#endif
}
