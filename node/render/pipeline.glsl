// Shared by warp.frag.glsl and mesh.frag.glsl, which include it (moderngl resolves the include).
//
// Content sampling reproduces cv2.warpPerspective(..., INTER_LINEAR, BORDER_CONSTANT, 0)
// in float arithmetic: bilinear interpolation between the four texels around a point given
// in content pixels (OpenCV convention: texel (x, y) has its centre at integer (x, y)),
// texels outside the content counting as 0. texelFetch + explicit weights, not the
// hardware filter, so the result does not depend on a GPU's 8-bit sub-texel precision.
//
// Then the node's luminance pipeline: value = LUT(clamp(gain * value)) per channel,
// or clamp(value) when apply_lut is 0; quantised to round(255 * value).
//
// With blend maps (BLEND 1; protos/blend.py, protos/spaces.py's blended_output), frames that
// apply the LUT become LUT(clamp(gain * (alpha * value + beta))) and are quantised with a 4x4
// ordered dither, floor(255 * value + t), so that a slow ramp scaled by the maps does not band.
// Without them (or for patterns, apply_lut 0) the output is what it was without blending, bit for bit.

// One program per variant (shaders.py's variant_defines puts these #define lines after the
// #version line; the renderer compiles each combination at its first use and keeps it), so that
// no frame pays for a path it does not take (llvmpipe runs a uniform's branches with masks, both
// sides):
//   CONTENT_KIND  1 RGB(A), 2 grey (1 or 2 channels, .r replicated), 3 planar YUV, 4 semi-planar YUV
//   FADE_FROM     -1 no fade; 0 a fade from black; 1..4 from a picture of that kind (content_from)
//   BLEND         1: blend maps are set (only with APPLY_LUT 1)
//   APPLY_LUT     1: gain, blend and LUT; 0: clamp(value) only (e.g. calibration patterns)

uniform sampler2D content;      // (H, W) texels, row 0 = top row of the image, never filtered
uniform sampler2D lut;          // (3, E - 1) RG32F: row c = channel c, texel k = (sample k, sample k + 1)
                                // of E at luminance k / (E - 1): one fetch per channel
uniform int lut_size;           // E >= 2
uniform float gain;
uniform sampler2D blend;        // (h, w) RGBA32F or RGBA16F: rgb = alpha, a = beta; row 0 = the output's
                                // bottom row (GL order); LINEAR, CLAMP_TO_EDGE (node/render/blend_texture.py)
uniform vec2 blend_xform;       // (1 / W, 1 / H): fragment -> texture coordinates (see blend_at)
uniform int out_rows;           // H, the output's rows (the dither counts rows from the top)
// A crossfade (node/fade.py, protos/fade.py): the picture shown before is mixed in, on the linear
// content values, before the gain, the blend and the LUT: mix(before, value, fade_mix).
uniform sampler2D content_from; // the picture before, sampled as content is (same size and space)
uniform float fade_mix;         // the new picture's share, 0..1
// A video frame's YUV planes (protos/yuv.py, node/yuv.py), converted here instead of on the CPU:
// content holds Y; planar: chroma_u and chroma_v hold U and V; semi-planar: chroma_u holds UV
// interleaved (NV12, P010). RGB = yuv_matrix * (Y, U, V) as sampled + yuv_offset (protos/yuv.py's
// yuv_affine), chroma bilinear at the luma position, clamped at its edges; luma as any content
// (outside: black).
uniform sampler2D chroma_u;
uniform sampler2D chroma_v;
uniform mat3 yuv_matrix;
uniform vec3 yuv_offset;
uniform vec4 chroma_xform;      // luma texel -> chroma texel: xy * chroma_xform.xy + chroma_xform.zw
uniform vec2 luma_scale;        // content pixel -> luma texel: (xy + 0.5) * luma_scale - 0.5
// The same for the picture a fade starts from (content_from holds its Y)
uniform sampler2D from_chroma_u;
uniform sampler2D from_chroma_v;
uniform mat3 from_yuv_matrix;
uniform vec3 from_yuv_offset;
uniform vec4 from_chroma_xform;
uniform vec2 from_luma_scale;

// Bilinear at xy (texels) with texels outside the texture weighing 0 (BORDER_CONSTANT 0);
// `weight` is the sum of the weights of the texels inside (1 well inside, 0 at one pixel out).
vec4 sample_border(sampler2D tex, vec2 xy, out float weight) {
    ivec2 size = textureSize(tex, 0);
    // At or beyond one pixel outside (or not a number) all four texels are outside: 0.
    // Inside, p0 is in -1..size-1 and p1 in 0..size, so only those two tests remain.
    if (!(all(greaterThan(xy, vec2(-1.0))) && all(lessThan(xy, vec2(size))))) {
        weight = 0.0;
        return vec4(0.0);
    }
    vec2 base = floor(xy);
    vec2 f = xy - base;
    ivec2 p0 = ivec2(base);
    ivec2 p1 = p0 + 1;
    // Fetch clamped, branch-free; the weights drop the texels outside.
    vec2 w0 = (1.0 - f) * vec2(greaterThanEqual(p0, ivec2(0)));
    vec2 w1 = f * vec2(lessThan(p1, size));
    ivec2 q0 = max(p0, ivec2(0));
    ivec2 q1 = min(p1, size - 1);
    vec4 top = w0.x * texelFetch(tex, q0, 0) + w1.x * texelFetch(tex, ivec2(q1.x, q0.y), 0);
    vec4 bottom = w0.x * texelFetch(tex, ivec2(q0.x, q1.y), 0) + w1.x * texelFetch(tex, q1, 0);
    weight = (w0.x + w1.x) * (w0.y + w1.y);
    return w0.y * top + w1.y * bottom;
}

vec3 sample_texture(sampler2D tex, int grey, vec2 xy) {
    float weight;
    vec4 t = sample_border(tex, xy, weight);
    return grey != 0 ? t.rrr : t.rgb;
}

// Bilinear at xy (texels) with the indices clamped to the texture (chroma's edges repeat).
vec4 sample_clamped(sampler2D tex, vec2 xy) {
    ivec2 size = textureSize(tex, 0);
    vec2 base = floor(xy);
    vec2 f = xy - base;
    ivec2 p0 = clamp(ivec2(base), ivec2(0), size - 1);
    ivec2 p1 = clamp(ivec2(base) + 1, ivec2(0), size - 1);
    vec4 top = (1.0 - f.x) * texelFetch(tex, p0, 0) + f.x * texelFetch(tex, ivec2(p1.x, p0.y), 0);
    vec4 bottom = (1.0 - f.x) * texelFetch(tex, ivec2(p0.x, p1.y), 0) + f.x * texelFetch(tex, p1, 0);
    return (1.0 - f.y) * top + f.y * bottom;
}

// sample_clamped of two textures of one size (planar U and V) at xy, with one set of indices: (U, V).
vec2 sample_clamped2(sampler2D tu, sampler2D tv, vec2 xy) {
    ivec2 size = textureSize(tu, 0);
    vec2 base = floor(xy);
    vec2 f = xy - base;
    ivec2 p0 = clamp(ivec2(base), ivec2(0), size - 1);
    ivec2 p1 = clamp(ivec2(base) + 1, ivec2(0), size - 1);
    ivec2 p2 = ivec2(p1.x, p0.y);
    ivec2 p3 = ivec2(p0.x, p1.y);
    vec2 top = (1.0 - f.x) * vec2(texelFetch(tu, p0, 0).r, texelFetch(tv, p0, 0).r)
               + f.x * vec2(texelFetch(tu, p2, 0).r, texelFetch(tv, p2, 0).r);
    vec2 bottom = (1.0 - f.x) * vec2(texelFetch(tu, p3, 0).r, texelFetch(tv, p3, 0).r)
                  + f.x * vec2(texelFetch(tu, p1, 0).r, texelFetch(tv, p1, 0).r);
    return (1.0 - f.y) * top + f.y * bottom;
}

// A YUV picture at content pixel xy: luma bilinear with texels outside weighing 0 (sample_border),
// so its edges fade to black as an RGB picture's do; the conversion is affine, so it is applied to
// the weighted sum: sum(w_i (M (y_i, u, v) + o)) = M (Y, W u, W v) + W o.
vec3 sample_yuv(sampler2D luma, sampler2D cu, sampler2D cv, int mode, mat3 m, vec3 o, vec4 cx, vec2 scale,
                vec2 xy) {
    vec2 l = (xy + 0.5) * scale - 0.5;
    float weight;
    float y = sample_border(luma, l, weight).r;
    if (weight == 0.0) {
        return vec3(0.0);
    }
    vec2 c = l * cx.xy + cx.zw;
    vec2 uv = mode == 2 ? sample_clamped(cu, c).rg : sample_clamped2(cu, cv, c);
    return m * vec3(y, uv * weight) + o * weight;
}

vec3 sample_content(vec2 xy) {
#if CONTENT_KIND >= 3
    return sample_yuv(content, chroma_u, chroma_v, CONTENT_KIND - 2, yuv_matrix, yuv_offset, chroma_xform,
                      luma_scale, xy);
#else
    return sample_texture(content, CONTENT_KIND - 1, xy);
#endif
}

// The frame's own content at xy, with the picture before mixed in while a fade is under way.
vec3 sample_faded(vec2 xy) {
    vec3 value = sample_content(xy);
#if FADE_FROM < 0
    return value;
#else
#if FADE_FROM >= 3
    vec3 before = sample_yuv(content_from, from_chroma_u, from_chroma_v, FADE_FROM - 2, from_yuv_matrix,
                             from_yuv_offset, from_chroma_xform, from_luma_scale, xy);
#elif FADE_FROM >= 1
    vec3 before = sample_texture(content_from, FADE_FROM - 1, xy);
#else
    vec3 before = vec3(0.0);
#endif
    return mix(before, value, fade_mix);
#endif
}

float lut_channel(float v, int channel) {
    float t = clamp(v, 0.0, 1.0) * float(lut_size - 1);
    int i = min(int(t), lut_size - 2);
    vec2 y = texelFetch(lut, ivec2(i, channel), 0).rg;
    return mix(y.x, y.y, t - float(i));
}

// The blend maps at this fragment: projector pixel (x, y) (OpenCV, rows from the top) reads the
// map at ((x + 0.5) w / W - 0.5, (y + 0.5) h / H - 0.5), bilinear between the four texels around it,
// clamped to the edge texels; the texture unit's filter does it, from texture coordinate
// gl_FragCoord.xy / (W, H) on the map stored bottom row first (one fetch; llvmpipe filters float32
// texels far faster than four texelFetch and our weights). The map has no mipmaps and minifies and
// magnifies alike (LINEAR), so the level of detail does not matter.
vec4 blend_at() {
    return texture(blend, gl_FragCoord.xy * blend_xform);
}

// The 4x4 Bayer threshold (B + 0.5) / 16 at this fragment, B = BAYER4[y % 4][x % 4] with y counted
// from the top row: B = 4 b(y & 1, x & 1) + b(y >> 1 & 1, x >> 1 & 1), b(y, x) = 2 (x ^ y) + y.
float dither_threshold() {
    int x = int(gl_FragCoord.x);
    int y = out_rows - 1 - int(gl_FragCoord.y);
    int lo = (((x ^ y) & 1) << 1) | (y & 1);
    int hi = ((((x ^ y) >> 1) & 1) << 1) | ((y >> 1) & 1);
    return (float(4 * lo + hi) + 0.5) / 16.0;
}

vec4 finish(vec3 value) {
    vec3 v = value;
#if APPLY_LUT
#if BLEND
    vec4 ab = blend_at();
    v = ab.rgb * v + ab.a;
#endif
    v = clamp(v * gain, 0.0, 1.0);
    v = vec3(lut_channel(v.r, 0), lut_channel(v.g, 1), lut_channel(v.b, 2));
#endif
    v = clamp(v, 0.0, 1.0);
    // Quantise here, to round(255 * v) (halves up), so the unorm8 framebuffer stores exactly
    // that level whether the driver's float->unorm conversion rounds or truncates
    // (+0.25 keeps k/255 from landing a hair below k under truncation). Blended: dithered.
#if APPLY_LUT && BLEND
    vec3 level = floor(v * 255.0 + dither_threshold());
#else
    vec3 level = floor(v * 255.0 + 0.5);
#endif
    return vec4((level + 0.25) / 255.0, 1.0);
}
