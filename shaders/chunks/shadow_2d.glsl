// Visibility of a receiver in the camera pass's 2D shadow maps (orthographic and perspective).
//
// The including stage declares NUM_MAPS_2D, NORMAL_OFFSET and PCF_RADIUS (and what the included
// chunks use).
#include "chunks/shadow_lookup.glsl"
#include "chunks/lighting.glsl"

#if NUM_MAPS_2D > 0
in vec4 v_map2d[NUM_MAPS_2D];              // u_map2d_matrix x world, from camera_pass.vert
uniform MAP2D u_map2d[NUM_MAPS_2D];
uniform mat4 u_map2d_matrix[NUM_MAPS_2D];  // world -> biased light clip (normal offset)
uniform mat4 u_map2d_view[NUM_MAPS_2D];    // world -> light view (receiver plane)
uniform vec4 u_map2d_range[NUM_MAPS_2D];   // near, far, unused, map size
// World size of a texel at light depth d: x + y * d (orthographic: y = 0; perspective: x = 0).
uniform vec2 u_map2d_texel[NUM_MAPS_2D];
// A texel along the map's x and y axes over that size (< 1 along the shorter side of an oblong fit).
uniform vec2 u_map2d_axes[NUM_MAPS_2D];

// Shadow of the receiver at p in 2D map m. `c` is the interpolated light coordinate from the
// vertex shader (bias matrix applied: xy in [0, 1]; for orthographic maps z is the linear depth
// t, for perspective ones w is the distance along the light's axis).
float visibility_2d_from(MAP2D map, vec4 c, int m, vec3 p, vec3 ng, float cos_l, float tan_l) {
    vec4 range = u_map2d_range[m];
    float span = range.y - range.x;
    float persp = u_map2d_texel[m].y;  // > 0: perspective, world texel size grows with depth
#if NORMAL_OFFSET
    float texel0 = u_map2d_texel[m].x + persp * c.w;
    vec3 q = p + ng * (u_bias.w * texel0 * sqrt(max(1.0 - cos_l * cos_l, 0.0)));
    c = u_map2d_matrix[m] * vec4(q, 1.0);
#endif
    vec2 uv = c.xy / c.w;
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return 1.0;
    float t = persp > 0.0 ? (c.w - range.x) / span : c.z;
    float texel = u_map2d_texel[m].x + persp * c.w;
    // Depth of the receiver's plane at a point moved by one texel (dx, dy) across the map:
    // orthographic rays change it by (n.x dx + n.y dy) / n.z, perspective rays through the light
    // by -depth (n.x dx + n.y dy) / (n . p) at first, and exactly by the Plane's divisor.
    vec3 nl = mat3(u_map2d_view[m]) * ng;
    vec2 slope = nl.xy / max(nl.z, 1e-6);
    if (persp > 0.0) {
        vec3 pv = (u_map2d_view[m] * vec4(p, 1.0)).xyz;
        slope = -c.w * nl.xy / min(dot(nl, pv), -1e-30);
    }
    Plane pl;
    pl.ref = t - bias_world(texel, tan_l) / span - u_bias_steps * ENC_STEP;
    pl.slope = clamp(slope, -PLANE_SLOPE_MAX, PLANE_SLOPE_MAX) * u_map2d_axes[m] * (texel / span);
    pl.persp = persp > 0.0 ? -pl.slope * span / c.w : vec2(0.0);
    return shadow_2d(map, uv, pl, range.w);
}

// Map m's visibility through one case per slot (FOR_EACH_SLOT, from Python): every array index
// is a constant, as dynamic indexing of sampler arrays is where drivers differ. The cases past
// NUM_MAPS_2D are never taken and compile away; MAP2D_SLOT keeps their indices in range.
#define MAP2D_SLOT(K) min(K, NUM_MAPS_2D - 1)
#define MAP2D_CASE(K) if (K < NUM_MAPS_2D && m == K) return visibility_2d_from(u_map2d[MAP2D_SLOT(K)], v_map2d[MAP2D_SLOT(K)], MAP2D_SLOT(K), p, ng, cos_l, tan_l);
float visibility_2d(int m, vec3 p, vec3 ng, float cos_l, float tan_l) {
    FOR_EACH_SLOT(MAP2D_CASE)
    return 1.0;
}
#endif
