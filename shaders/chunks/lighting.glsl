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
// 1 - cos(outer), 1 - cos(inner), worked out in float64 (2 sin^2 of half the angle): a cone a
// hundredth of a degree wide is 1 - 1.5e-8 in cos, which float32 rounds to 1.
uniform vec2 u_light_cone[NUM_LIGHTS];
// The point of each spot's axis nearest the scene's centre (origin-relative), and the distance
// from the light to it along the axis, worked out in float64: a point's angle off the axis is
// then measured with small numbers only. Through the light's own position (5e10 units away,
// where float32 steps by 4096) the direction to the light is no finer than 1e-7 radians.
uniform vec3 u_light_axis_point[NUM_LIGHTS];
uniform float u_light_axis_offset[NUM_LIGHTS];
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
            // glTF's smooth falloff between the cones, smoothstep(cos outer, cos inner, cos),
            // taken in 1 - cos, from tan^2 of the angle off the axis (x): 1 - cos =
            // x / (sqrt(1 + x) (sqrt(1 + x) + 1)) keeps float32's relative precision at small
            // angles, where cos itself rounds to 1 (a spot 1e5 units away whose cone just holds
            // a scene a few units across lit nothing). Behind the light: outside every cone.
            vec3 axis = u_light_direction[i];
            vec3 q = p - u_light_axis_point[i];
            float along_q = dot(q, axis);
            float along = along_q + u_light_axis_offset[i];
            vec3 perp = q - along_q * axis;
            float x = dot(perp, perp) / max(along * along, 1e-30);
            float r = sqrt(1.0 + x);
            float off = along > 0.0 ? x / (r * (r + 1.0)) : 2.0;
            vec2 cone = u_light_cone[i];
            float t = clamp((cone.x - off) / (cone.x - cone.y), 0.0, 1.0);
            atten *= t * t * (3.0 - 2.0 * t);
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
