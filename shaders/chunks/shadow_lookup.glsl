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
    // Level 0 given: the map has no mipmaps, and llvmpipe then skips the derivatives.
    return textureLod(map, vec3(uv, ref), 0.0);  // GL_COMPARE_REF_TO_TEXTURE, GL_LEQUAL
#else
    return step(ref, decode_depth(textureLod(map, uv, 0.0)));
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
    return textureGrad(map, vec4(uv, layer, ref), vec2(0.0), vec2(0.0));  // level 0, as above
#else
    return step(ref, decode_depth(textureLod(map, vec3(uv, layer), 0.0)));
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
    return textureGrad(map, vec4(dir, ref), vec3(0.0), vec3(0.0));  // level 0, as above
#else
    return step(ref, decode_depth(textureLod(map, dir, 0.0)));
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
