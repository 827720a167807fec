// Depth encodings of a shadow map. Every encoding stores the linear light-space depth
// t = (distance along the light's axis - near) / (far - near), in [0, 1].
//
// ENC_R8    one 8-bit channel (WebGL guide, Shadow.js).
// ENC_RG8   ARM's two-channel scheme: R = integer part x 0.1, G = fractional part, applied to
//           10 t (the range is normalised per scene instead of the fixed [-10, 10]).
// ENC_RGB8  24 bits in RGB, least significant byte in R (packDepth888, packed-depth blog).
// ENC_RGBA8 32 bits in RGBA, most significant byte in R (WebGL guide, Shadow_highp.js).
// ENC_DEPTH a depth texture (16-bit or 32-bit float, the plan's depth_bits), read as plain
//           depths (OpenGL guide; the compare is chunks/shadow_lookup.glsl's).
//
// The ids (ENC_*) come from Python (renderer/shader_constants.py, CPU
// mirror in renderer/encodings.py); the including stage declares ENCODING.
//
// The byte packings are exact: scaling by powers of two and fract() lose no bits in float32,
// each channel keeps one byte (the guide's bit mask), and bytes are written as byte/255 so that
// the UNORM8 store rounds back to the same byte.

// One step of the stored depth (the unit of the quantisation bias and of the polygon offset)
// is each map's own, a uniform from Python (ShadowMap.step): a depth texture has 16 or 32 bits
// as its plan chose.
#if ENCODING != ENC_R8 && ENCODING != ENC_RG8 && ENCODING != ENC_RGB8 && ENCODING != ENC_RGBA8 && ENCODING != ENC_DEPTH
#error ENCODING is none of the ENC_* ids
#endif

// Four bytes of t: b0 the most significant, each as byte/256.
vec4 depth_bytes(float t) {
    t = clamp(t, 0.0, 1.0 - 1.0 / 16777216.0);
    vec4 f = fract(t * vec4(1.0, 256.0, 65536.0, 16777216.0));
    return f - f.yzww * vec4(1.0 / 256.0, 1.0 / 256.0, 1.0 / 256.0, 0.0);
}

vec4 encode_depth(float t) {
#if ENCODING == ENC_R8
    return vec4(clamp(t, 0.0, 1.0), 0.0, 0.0, 1.0);
#elif ENCODING == ENC_RG8
    float value = clamp(t, 0.0, 1.0) * 10.0;
    float whole = floor(value);
    return vec4(whole * 0.1, value - whole, 0.0, 1.0);
#elif ENCODING == ENC_RGB8
    vec4 b = depth_bytes(t) * (256.0 / 255.0);
    return vec4(b.z, b.y, b.x, 1.0);
#else
    return depth_bytes(t) * (256.0 / 255.0);
#endif
}

float decode_depth(vec4 c) {
#if ENCODING == ENC_R8
    return c.r;
#elif ENCODING == ENC_RG8
    return (floor(c.r * 10.0 + 0.5) + c.g) * 0.1;
#elif ENCODING == ENC_RGB8
    vec3 b = floor(c.rgb * 255.0 + 0.5);
    return dot(b, vec3(1.0 / 16777216.0, 1.0 / 65536.0, 1.0 / 256.0));
#else
    vec4 b = floor(c * 255.0 + 0.5);
    return dot(b, vec4(1.0 / 256.0, 1.0 / 65536.0, 1.0 / 16777216.0, 1.0 / 4294967296.0));
#endif
}
