// Visibility of a receiver in the camera pass's cascaded shadow maps (directional lights whose
// view the plan split into cascades). A cascaded light's maps are the layers of one array
// texture, so the cascade a pixel reads is a texture coordinate, not a choice among samplers.
//
// The including stage declares NUM_MAPS_CSM, NORMAL_OFFSET and PCF_RADIUS (and what the included
// chunks use). Per-cascade uniforms are indexed slot * MAX_CASCADES + cascade.
#include "chunks/shadow_lookup.glsl"
#include "chunks/lighting.glsl"

#if NUM_MAPS_CSM > 0
uniform MAPARRAY u_mapcsm[NUM_MAPS_CSM];
uniform mat4 u_csm_matrix[NUM_MAPS_CSM * MAX_CASCADES];  // world -> biased light clip
uniform mat4 u_csm_view[NUM_MAPS_CSM * MAX_CASCADES];    // world -> light view (receiver plane)
#if NORMAL_OFFSET
uniform float u_csm_texel[NUM_MAPS_CSM * MAX_CASCADES];  // world size of one texel (larger side)
#endif
// The receiver plane's factors, worked out once per frame (camera_pass.py,
// `cascade_plane_factors`) as a software rasterizer would divide them again on every pixel: xy,
// the stored depth's change per texel along x and y per unit of tangent; z, the texel's size in
// stored depth (its world size over far - near); w, the quantisation bias in stored depth.
uniform vec4 u_csm_depth[NUM_MAPS_CSM * MAX_CASCADES];
// Camera distances along the view axis: where each cascade ends, and the band before that
// end over which it fades into the next one.
uniform vec2 u_csm_split[NUM_MAPS_CSM * MAX_CASCADES];
uniform float u_csm_size[NUM_MAPS_CSM];                  // texels per side of every layer
// The view axis and the eye's place along it: view depth = dot(vec4(p, 1), u_camera_forward).
uniform vec4 u_camera_forward;

// Shadow of the receiver at p in cascade k of array map `map` (orthographic, like
// visibility_2d_from for an orthographic 2D map).
float visibility_layer(MAPARRAY map, int j, float layer, float size, vec3 p, vec3 ng,
                       float cos_l, float tan_l) {
    vec3 q = p;
#if NORMAL_OFFSET
    q = p + ng * (u_bias.w * u_csm_texel[j] * sqrt(max(1.0 - cos_l * cos_l, 0.0)));
#endif
    vec4 c = u_csm_matrix[j] * vec4(q, 1.0);
    vec2 uv = c.xy;
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return 1.0;
    vec4 k = u_csm_depth[j];
    vec3 nl = mat3(u_csm_view[j]) * ng;
    Plane pl;
    pl.ref = c.z - bias_world(k.z, tan_l) - k.w;
    pl.slope = clamp(nl.xy / max(nl.z, 1e-6), -PLANE_SLOPE_MAX, PLANE_SLOPE_MAX) * k.xy;
    pl.persp = vec2(0.0);  // orthographic
    return shadow_layer(map, uv, layer, pl, size);
}

// Visibility through `count` cascades of slot s by the camera distance z: the first cascade
// whose end lies beyond z, faded into the next one across the band before that end. `chosen`
// is the cascade read (the nearer one in a band).
float visibility_csm_from(MAPARRAY map, int s, int count, float z, vec3 p, vec3 ng,
                          float cos_l, float tan_l, out int chosen) {
    int k = 0;
    for (int j = 0; j < MAX_CASCADES - 1; ++j) {
        if (j < count - 1 && z > u_csm_split[s * MAX_CASCADES + j].x) k = j + 1;
    }
    chosen = k;
    int j = s * MAX_CASCADES + k;
    float size = u_csm_size[s];
    float v = visibility_layer(map, j, float(k), size, p, ng, cos_l, tan_l);
    vec2 split = u_csm_split[j];
    if (k < count - 1 && split.y > 0.0) {
        float t = (z - (split.x - split.y)) / split.y;
        if (t > 0.0) {
            float next = visibility_layer(map, j + 1, float(k + 1), size, p, ng, cos_l, tan_l);
            v = mix(v, next, min(t, 1.0));
        }
    }
    return v;
}

// One case per slot (see visibility_2d in chunks/shadow_2d.glsl): constant sampler indices.
#define MAPCSM_SLOT(K) min(K, NUM_MAPS_CSM - 1)
#define MAPCSM_CASE(K) if (K < NUM_MAPS_CSM && s == K) return visibility_csm_from(u_mapcsm[MAPCSM_SLOT(K)], MAPCSM_SLOT(K), count, z, p, ng, cos_l, tan_l, chosen);
float visibility_csm(int s, int count, float z, vec3 p, vec3 ng, float cos_l, float tan_l,
                     out int chosen) {
    chosen = -1;
    FOR_EACH_SLOT(MAPCSM_CASE)
    return 1.0;
}
#endif
