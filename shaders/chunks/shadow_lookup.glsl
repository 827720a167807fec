// Shadow-map lookups: 1 where the receiver is lit, 0 where a caster is in front of it, fractions
// with PCF. Every texel read is compared against the receiver's plane at that texel's own
// centre (receiver-plane depth bias, taken to the texel): the light pass stored depth at texel
// centres, so a planar receiver meets its own stored depth exactly there, at any angle to the
// light, and needs no slope-scaled bias to stay free of acne, and a caster just above it (a
// decal, a lip) still shadows it.
//
// The maps are read as plain textures (no hardware compare): a depth texture's value is the
// linear depth itself, a byte encoding's is decoded (chunks/depth_encoding.glsl).
//   hard filter: the texel under the lookup point.
//   PCF, depth encoding: (2R+2)^2 texels, gathered four at a time, weighted like (2R+1)^2
//       bilinear taps (a tent: 1 - f, 1, ..., 1, f per axis).
//   PCF, byte encodings: (2R+1)^2 texels under as many taps, equal weights (bytes do not
//       interpolate).
//
// The including stage declares ENCODING, FILTER_PCF and PCF_RADIUS.
#include "chunks/depth_encoding.glsl"

#define MAP2D sampler2D
#define MAPCUBE sampler2DArray  // a cube map's six faces as layers, +X, -X, +Y, -Y, +Z, -Z
#define MAPARRAY sampler2DArray

#if ENCODING == ENC_DEPTH
#define STORED(v) (v).r
#else
#define STORED(v) decode_depth(v)
#endif

// The receiver's plane in a map's texels: its stored-depth units at the lookup point (`ref`,
// bias subtracted) and at a point moved by d texels,
//     ref + dot(slope, d) / (1 + dot(persp, d)),
// exact for both projections: linear in an orthographic map (persp = 0), and in a perspective
// one the depth along the ray through the moved point, which is what that texel stored. A plane
// steep to the light changes the divisor by several per cent a texel, so a first-order
// (linear) plane would need a slope bias again there.
struct Plane {
    float ref;
    vec2 slope;  // per texel at d = 0
    vec2 persp;  // perspective maps: the relative change of the ray's depth per texel
};

// The divisor is kept positive: a texel whose ray would meet the plane behind the light (a
// plane edge-on to it) reads as far behind every caster.
float plane_at(Plane pl, vec2 d) {
    return pl.ref + dot(pl.slope, d) / max(1.0 + dot(pl.persp, d), 0.1);
}

vec4 plane_at4(Plane pl, vec4 dx, vec4 dy) {
    return pl.ref + (pl.slope.x * dx + pl.slope.y * dy)
        / max(1.0 + pl.persp.x * dx + pl.persp.y * dy, vec4(0.1));
}

// Lit (1) where the receiver's plane lies at or in front of the stored depth.
float lit(float ref, float stored) {
    return step(ref, stored);
}

// Four texels' lit values from a gathered quad (textureGather's order: x (0, 1), y (1, 1),
// z (1, 0), w (0, 0) in texels from the quad's lower-left texel). `f` is the lookup point's
// position past that texel's centre, in texels, for the quad at offset `o` from the lookup.
vec4 lit_quad(vec4 stored, Plane pl, vec2 f, vec2 o) {
    vec4 dx = vec4(0.0, 1.0, 1.0, 0.0) + (o.x - f.x);
    vec4 dy = vec4(1.0, 1.0, 0.0, 0.0) + (o.y - f.y);
    return step(plane_at4(pl, dx, dy), stored);
}

// Tent weights of a gathered quad whose lower-left texel is `k` texels (per axis) from the first
// texel of the (2R+2)-texel footprint: 1 - f for the first texel, f for the last, 1 between.
vec4 tent_quad(vec2 k, vec2 f) {
    float last = float(2 * PCF_RADIUS + 1);
    vec2 w0 = mix(vec2(1.0), 1.0 - f, equal(k, vec2(0.0)));
    vec2 w1 = mix(vec2(1.0), f, equal(k + 1.0, vec2(last)));
    return vec4(w0.x * w1.y, w1.x * w1.y, w1.x * w0.y, w0.x * w0.y);
}

// Taps a PCF kernel averages over: (2R+1)^2.
const float PCF_TAPS = float((2 * PCF_RADIUS + 1) * (2 * PCF_RADIUS + 1));

// One gathered quad's share of the tent-weighted PCF sum (x) and its weight (y): the quad at
// offset `o` (texels, from -R in steps of 2) from the lookup, `f` as in lit_quad. The weights
// add up to PCF_TAPS but for rounding: the sum is divided by their own total, so that a pixel
// every texel lights reads exactly 1, as it does where no lookup is drawn at all.
vec2 gathered_share(vec4 stored, Plane pl, vec2 f, vec2 o) {
    vec4 w = tent_quad(o + float(PCF_RADIUS), f);
    return vec2(dot(lit_quad(stored, pl, f, o), w), dot(w, vec4(1.0)));
}

float shadow_2d(MAP2D map, vec2 uv, Plane pl, float size) {
    vec2 st = uv * size;
#if FILTER_PCF && ENCODING == ENC_DEPTH
    vec2 f = fract(st - 0.5);
    vec2 corner = floor(st - 0.5) + 1.0;  // texel coordinates of the shared corner
    vec2 sum = vec2(0.0);
    for (int y = -PCF_RADIUS; y <= PCF_RADIUS; y += 2) {
        for (int x = -PCF_RADIUS; x <= PCF_RADIUS; x += 2) {
            vec2 o = vec2(float(x), float(y));
            sum += gathered_share(textureGather(map, (corner + o) / size), pl, f, o);
        }
    }
    return sum.x / sum.y;
#else
    ivec2 texel = ivec2(clamp(floor(st), 0.0, size - 1.0));
    vec2 c = floor(st) + 0.5 - st;  // the texel centre from the lookup point
#if FILTER_PCF
    float sum = 0.0;
    for (int y = -PCF_RADIUS; y <= PCF_RADIUS; ++y) {
        for (int x = -PCF_RADIUS; x <= PCF_RADIUS; ++x) {
            ivec2 o = ivec2(x, y);
            ivec2 at = clamp(texel + o, ivec2(0), ivec2(int(size) - 1));
            sum += lit(plane_at(pl, vec2(o) + c), STORED(texelFetch(map, at, 0)));
        }
    }
    return sum / PCF_TAPS;
#else
    return lit(plane_at(pl, c), STORED(texelFetch(map, texel, 0)));
#endif
#endif
}

// Four texels' lit values from a gathered quad, like lit_quad, for a lookup at `st` (texels)
// whose quad's lower-left texel centre is `c0` (texels), in a map of `size` texels: each texel is
// compared against the plane at the centre of the texel the read returns, clamped to the map
// (at a cube face's edge the read clamps to the edge texel, and so does the plane).
vec4 lit_quad_clamped(vec4 stored, Plane pl, vec2 st, vec2 c0, float size) {
    vec4 dx = clamp(vec4(0.0, 1.0, 1.0, 0.0) + c0.x, 0.5, size - 0.5) - st.x;
    vec4 dy = clamp(vec4(1.0, 1.0, 0.0, 0.0) + c0.y, 0.5, size - 0.5) - st.y;
    return step(plane_at4(pl, dx, dy), stored);
}

// The same on layer `layer` of an array map: cascades, and the six faces of a cube map. Texels
// past the layer's edge read as its edge texels and are compared at those texels' centres.
float shadow_layer(MAPARRAY map, vec2 uv, float layer, Plane pl, float size) {
    vec2 st = uv * size;
#if FILTER_PCF && ENCODING == ENC_DEPTH
    vec2 f = fract(st - 0.5);
    vec2 corner = floor(st - 0.5) + 1.0;
    vec2 sum = vec2(0.0);
    for (int y = -PCF_RADIUS; y <= PCF_RADIUS; y += 2) {
        for (int x = -PCF_RADIUS; x <= PCF_RADIUS; x += 2) {
            vec2 o = vec2(float(x), float(y));
            vec4 stored = textureGather(map, vec3((corner + o) / size, layer));
            vec4 w = tent_quad(o + float(PCF_RADIUS), f);
            sum += vec2(dot(lit_quad_clamped(stored, pl, st, corner + o - 0.5, size), w),
                        dot(w, vec4(1.0)));
        }
    }
    return sum.x / sum.y;  // see gathered_share
#else
    ivec2 texel = ivec2(clamp(floor(st), 0.0, size - 1.0));
    int l = int(layer);
#if FILTER_PCF
    float sum = 0.0;
    for (int y = -PCF_RADIUS; y <= PCF_RADIUS; ++y) {
        for (int x = -PCF_RADIUS; x <= PCF_RADIUS; ++x) {
            ivec2 at = clamp(texel + ivec2(x, y), ivec2(0), ivec2(int(size) - 1));
            float stored = STORED(texelFetch(map, ivec3(at, l), 0));
            sum += lit(plane_at(pl, vec2(at) + 0.5 - st), stored);
        }
    }
    return sum / PCF_TAPS;
#else
    return lit(plane_at(pl, vec2(texel) + 0.5 - st), STORED(texelFetch(map, ivec3(texel, l), 0)));
#endif
#endif
}

// A cube map's face as seen from a lookup direction: its layer (`face`, in GL's order +X, -X,
// +Y, -Y, +Z, -Z), `s_axis`, `t_axis`, the world directions in which the face's s and t grow
// (the cube-map face table of the GL specification), and `st`, the lookup's face coordinates in
// [0, 1]. The faces are rendered and stored as the layers of a 2D array texture: the lookup
// picks the face here anyway, and an array read costs much less than a cube-map read on a
// software rasterizer.
void cube_face(vec3 dir, out float face, out vec3 s_axis, out vec3 t_axis, out vec2 st) {
    vec3 a = abs(dir);
    if (a.x >= a.y && a.x >= a.z) {
        float sg = sign(dir.x);
        face = dir.x < 0.0 ? 1.0 : 0.0;
        s_axis = vec3(0.0, 0.0, -sg);
        t_axis = vec3(0.0, -1.0, 0.0);
    } else if (a.y >= a.z) {
        float sg = sign(dir.y);
        face = dir.y < 0.0 ? 3.0 : 2.0;
        s_axis = vec3(1.0, 0.0, 0.0);
        t_axis = vec3(0.0, 0.0, sg);
    } else {
        float sg = sign(dir.z);
        face = dir.z < 0.0 ? 5.0 : 4.0;
        s_axis = vec3(sg, 0.0, 0.0);
        t_axis = vec3(0.0, -1.0, 0.0);
    }
    float ma = max(a.x, max(a.y, a.z));
    st = vec2(dot(dir, s_axis), dot(dir, t_axis)) / ma * 0.5 + 0.5;
}
