// Visibility of a receiver in the camera pass's cube shadow maps (point lights, wide spots), whose
// six faces are the layers of an array texture (cube_face() in chunks/shadow_lookup.glsl).
//
// The including stage declares NUM_MAPS_CUBE, NORMAL_OFFSET and PCF_RADIUS (and what the
// included chunks use).
#include "chunks/shadow_lookup.glsl"
#include "chunks/lighting.glsl"

#if NUM_MAPS_CUBE > 0
uniform MAPCUBE u_mapcube[NUM_MAPS_CUBE];
uniform vec3 u_mapcube_position[NUM_MAPS_CUBE];
uniform vec4 u_mapcube_range[NUM_MAPS_CUBE];  // near, far, map size, one step of the stored depth
// Quotients of those worked out once per frame (camera_pass.py, `cube_plane_factors`), as a
// software rasterizer would divide them again on every pixel: 1 / (far - near); a texel's world
// size per unit of face depth (2 / size: 90-degree faces); the same in stored depth (over
// far - near); the quantisation bias in stored depth.
uniform vec4 u_mapcube_depth[NUM_MAPS_CUBE];

// The shadow lookup in cube map m, one case per slot (see visibility_2d in chunks/shadow_2d.glsl):
// constant sampler-array indices only.
#define MAPCUBE_SLOT(K) min(K, NUM_MAPS_CUBE - 1)
#define MAPCUBE_CASE(K) if (K < NUM_MAPS_CUBE && m == K) return shadow_layer(u_mapcube[MAPCUBE_SLOT(K)], uv, face, pl, range.z);

// Shadow of the receiver at p in cube map m.
float visibility_cube(int m, vec3 p, vec3 ng, float cos_l, float tan_l) {
    vec4 range = u_mapcube_range[m];
    vec4 k = u_mapcube_depth[m];
    vec3 d = p - u_mapcube_position[m];
    vec3 a = abs(d);
    float depth = max(a.x, max(a.y, a.z));
#if NORMAL_OFFSET
    float texel = depth * k.y;
    vec3 q = p + ng * (u_bias.w * texel * sqrt(max(1.0 - cos_l * cos_l, 0.0)));
    d = q - u_mapcube_position[m];
    a = abs(d);
    depth = max(a.x, max(a.y, a.z));
#endif
    float face;
    vec3 s_axis;
    vec3 t_axis;
    vec2 uv;
    cube_face(d, face, s_axis, t_axis, uv);
    float t = (depth - range.x) * k.x;
    // A point moved by w across the face meets the receiver's plane at face depth
    // depth (n . d) / (n . (d + w)): at first a change of -depth (n . w) / (n . d), exactly the
    // Plane's divisor.
    vec2 slope = clamp(-depth * vec2(dot(ng, s_axis), dot(ng, t_axis)) / min(dot(ng, d), -1e-30),
                       -PLANE_SLOPE_MAX, PLANE_SLOPE_MAX);
    float texel_t = depth * k.z;  // the texel's size in stored depth, which bias_world scales
    Plane pl;
    pl.ref = t - bias_world(texel_t, tan_l) - k.w;
    pl.slope = slope * texel_t;
    pl.persp = -slope * k.y;  // the slope in stored depth times span over depth
    FOR_EACH_SLOT(MAPCUBE_CASE)
    return 1.0;
}
#endif
