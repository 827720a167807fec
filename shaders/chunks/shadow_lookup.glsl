// Shadow-map lookups: 1 where the receiver is lit, 0 where a caster is in front of it, fractions
// with PCF. `ref` is the receiver's linear light depth minus its bias; `dref` is how `ref` changes
// per texel of offset along the map's two axes (receiver-plane depth bias), so every PCF tap is
// compared against the receiver's own plane instead of a bias widened for the whole kernel.
//
// The including stage declares ENCODING, FILTER_PCF and PCF_RADIUS.
#include "chunks/depth_encoding.glsl"

#if ENCODING == ENC_DEPTH
#define MAP2D sampler2DShadow
#define MAPCUBE samplerCubeShadow
#define MAPARRAY sampler2DArrayShadow
#else
#define MAP2D sampler2D
#define MAPCUBE samplerCube
#define MAPARRAY sampler2DArray
#endif

float compare_2d(MAP2D map, vec2 uv, float ref) {
#if ENCODING == ENC_DEPTH
    return texture(map, vec3(uv, ref));  // GL_COMPARE_REF_TO_TEXTURE, GL_LEQUAL
#else
    return step(ref, decode_depth(texture(map, uv)));
#endif
}

float shadow_2d(MAP2D map, vec2 uv, float ref, vec2 dref, float size) {
#if FILTER_PCF
    float sum = 0.0;
    for (int y = -PCF_RADIUS; y <= PCF_RADIUS; ++y) {
        for (int x = -PCF_RADIUS; x <= PCF_RADIUS; ++x) {
            vec2 o = vec2(float(x), float(y));
            sum += compare_2d(map, uv + o / size, ref + dot(dref, o));
        }
    }
    return sum / float((2 * PCF_RADIUS + 1) * (2 * PCF_RADIUS + 1));
#else
    return compare_2d(map, uv, ref);
#endif
}

// The same on layer `layer` of an array map (cascades).
float compare_layer(MAPARRAY map, vec2 uv, float layer, float ref) {
#if ENCODING == ENC_DEPTH
    return texture(map, vec4(uv, layer, ref));
#else
    return step(ref, decode_depth(texture(map, vec3(uv, layer))));
#endif
}

float shadow_layer(MAPARRAY map, vec2 uv, float layer, float ref, vec2 dref, float size) {
#if FILTER_PCF
    float sum = 0.0;
    for (int y = -PCF_RADIUS; y <= PCF_RADIUS; ++y) {
        for (int x = -PCF_RADIUS; x <= PCF_RADIUS; ++x) {
            vec2 o = vec2(float(x), float(y));
            sum += compare_layer(map, uv + o / size, layer, ref + dot(dref, o));
        }
    }
    return sum / float((2 * PCF_RADIUS + 1) * (2 * PCF_RADIUS + 1));
#else
    return compare_layer(map, uv, layer, ref);
#endif
}

float compare_cube(MAPCUBE map, vec3 dir, float ref) {
#if ENCODING == ENC_DEPTH
    return texture(map, vec4(dir, ref));
#else
    return step(ref, decode_depth(texture(map, dir)));
#endif
}

// `axis_u`, `axis_v`: the face's two axes scaled to one texel at the receiver's face depth.
float shadow_cube(MAPCUBE map, vec3 dir, float ref, vec2 dref, vec3 axis_u, vec3 axis_v) {
#if FILTER_PCF
    float sum = 0.0;
    for (int y = -PCF_RADIUS; y <= PCF_RADIUS; ++y) {
        for (int x = -PCF_RADIUS; x <= PCF_RADIUS; ++x) {
            vec2 o = vec2(float(x), float(y));
            sum += compare_cube(map, dir + o.x * axis_u + o.y * axis_v, ref + dot(dref, o));
        }
    }
    return sum / float((2 * PCF_RADIUS + 1) * (2 * PCF_RADIUS + 1));
#else
    return compare_cube(map, dir, ref);
#endif
}
