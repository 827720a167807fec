// Shading terms of the camera pass: sRGB conversions, the lights' falloff, and the depth bias.
//
// The including stage declares NUM_LIGHTS, LIGHT_TYPES, HAS_SPOT, HAS_POSITIONAL, NUM_MAPS_2D,
// NUM_MAPS_CUBE and NUM_MAPS_CSM.

vec3 srgb_to_linear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(0.04045, c));
}

vec3 linear_to_srgb(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
}

#if NUM_LIGHTS > 0
// The light types are part of the variant (LIGHT_TYPES lists a LIGHT_* id per light): with
// constant types the unrolled light loop keeps only each light's own code path.
const int LIGHT_TYPE[NUM_LIGHTS] = int[NUM_LIGHTS](LIGHT_TYPES);
uniform vec3 u_light_position[NUM_LIGHTS];
uniform vec3 u_light_direction[NUM_LIGHTS];  // the way the light travels
uniform vec3 u_light_radiance[NUM_LIGHTS];   // colour x intensity
#if HAS_SPOT
uniform vec2 u_light_cone[NUM_LIGHTS];       // cos(outer), cos(inner)
#endif
#if HAS_POSITIONAL
uniform float u_light_range[NUM_LIGHTS];     // 0: unlimited
#endif

// Light i at p: sets `l`, the unit vector towards the light, and returns the falloff (glTF's
// smooth range window and a spot's cone); directional lights get 1.
float light_attenuation(int i, vec3 p, out vec3 l) {
    l = -u_light_direction[i];
    float atten = 1.0;
#if HAS_POSITIONAL
    if (LIGHT_TYPE[i] != LIGHT_DIRECTIONAL) {
        vec3 d = u_light_position[i] - p;
        float dist = length(d);
        l = d / max(dist, 1e-30);
        float r = u_light_range[i];
        if (r > 0.0) {
            float x = clamp(1.0 - pow(dist / r, 4.0), 0.0, 1.0);
            atten = x * x;
        }
#if HAS_SPOT
        if (LIGHT_TYPE[i] == LIGHT_SPOT) {
            atten *= smoothstep(u_light_cone[i].x, u_light_cone[i].y,
                                dot(-l, u_light_direction[i]));
        }
#endif
    }
#endif
    return atten;
}
#endif

#if NUM_MAPS_2D > 0 || NUM_MAPS_CUBE > 0 || NUM_MAPS_CSM > 0
uniform vec4 u_bias;         // constant, slope, slope max, normal offset (texels)
// PLANE_SLOPE_MAX (injected): the steepest receiver plane (tan of its angle to the light) the
// per-texel comparison follows, that of the most grazing surface that still counts as facing the
// light; the bias's own slope term stops at slope_max. A plane compared at each texel's centre
// is exact at any angle: a lower clamp put false shadow on every surface steeper than it.

// Depth bias at a receiver whose texel has size `texel`, for a surface at angle acos(cos_l) to
// the light: a texel-sized constant plus the depth change across a texel, in the units of
// `texel` (the lookups pass its size in stored depth: texel / (far - near)). The quantisation
// bias (`shadows.bias.quantisation_steps` steps of each map's stored depth) comes with each
// map's uniforms.
float bias_world(float texel, float tan_l) {
    return texel * (u_bias.x + u_bias.y * min(tan_l, u_bias.z));
}
#endif
