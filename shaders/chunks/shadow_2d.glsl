// Visibility of a receiver in the camera pass's 2D shadow maps (orthographic and perspective).
//
// The including stage declares NUM_MAPS_2D, MAP2D_PERSPECTIVE, NORMAL_OFFSET and PCF_RADIUS (and
// what the included chunks use).
#include "chunks/shadow_lookup.glsl"
#include "chunks/lighting.glsl"

#if NUM_MAPS_2D > 0
in vec4 v_map2d[NUM_MAPS_2D];              // u_map2d_matrix x world, from camera_pass.vert
uniform MAP2D u_map2d[NUM_MAPS_2D];
// World -> biased light clip, its z row the stored depth t for both projections (see
// camera_pass.map2d_matrix); the normal offset transforms its moved point with it.
uniform mat4 u_map2d_matrix[NUM_MAPS_2D];
uniform vec4 u_map2d_range[NUM_MAPS_2D];   // near, far, one step of the stored depth, map size
#if NORMAL_OFFSET
// World size of a texel at light depth d: x + y * d (orthographic: y = 0; perspective: x = 0).
uniform vec2 u_map2d_texel[NUM_MAPS_2D];
#endif
// The receiver plane's factors, quotients of the map's size, depth range, texel and axes worked
// out once per frame (camera_pass.py, `map2d_plane_factors`): a software rasterizer would divide
// them again on every pixel. A perspective map's factors are per unit of the lookup's depth w
// (its texel grows with w).
//   plane: xy, the tangent per unit of the plane's coefficients (a, b) (see below);
//          zw, the stored depth's change per texel per unit of tangent.
//   depth: x, the texel's size in stored depth (texel / span); y, the quantisation bias in stored
//          depth; z, span (far - near).
uniform vec4 u_map2d_plane[NUM_MAPS_2D];
uniform vec3 u_map2d_depth[NUM_MAPS_2D];
// Per slot, 1 for a perspective map (spot lights), 0 for an orthographic one: a constant of the
// variant, as a runtime choice would run both projections' code on every pixel.
const int MAP2D_PERSP[NUM_MAPS_2D] = int[NUM_MAPS_2D](MAP2D_PERSPECTIVE);

// The screen derivatives of every slot's light coordinate, which give the receiver's plane.
// Taken in main() where control flow is uniform (derivatives are undefined inside branches).
struct Map2dDerivatives {
    vec4 dx[NUM_MAPS_2D];
    vec4 dy[NUM_MAPS_2D];
};

Map2dDerivatives map2d_derivatives() {
    Map2dDerivatives d;
    for (int k = 0; k < NUM_MAPS_2D; ++k) {
        d.dx[k] = dFdx(v_map2d[k]);
        d.dy[k] = dFdy(v_map2d[k]);
    }
    return d;
}

// Shadow of the receiver at p in 2D map m. `c` is the interpolated light coordinate from the
// vertex shader (bias matrix applied: xy in [0, 1] after the divide by w; z is the stored linear
// depth t, w a perspective map's distance along its axis), `cx` and `cy` its screen
// derivatives; `ng` and `cos_l` serve the normal offset only. A perspective map's depth is read
// from t, not from w: far from the light w is large and float32 keeps little of w - near.
//
// The receiver's plane comes from the derivatives, with no normal: c's components are affine in
// world space, so on a triangle the depth is an affine function of c.x and c.y, and the two
// screen steps give its coefficients (a, b):
//   orthographic: t = t0 + (a, b) . (uv - uv0), a change of (a, b) / size per texel;
//   perspective: w = a x + b y + e, so at map point uv the depth is e / (1 - (a, b) . uv) and a
//   texel step d multiplies it by 1 / (1 - k . d), k = (w0 / e) (a, b) / size: the Plane's
//   divisor, and w0 k / span its slope at d = 0.
float visibility_2d_from(MAP2D map, vec4 c, vec4 cx, vec4 cy, int m, bool persp, vec3 p,
                         vec3 ng, float cos_l) {
    vec4 range = u_map2d_range[m];
    float size = range.w;
    vec4 k = u_map2d_plane[m];
    vec3 z = u_map2d_depth[m];
#if NORMAL_OFFSET
    vec2 tx = u_map2d_texel[m];
    float texel0 = persp ? tx.y * c.w : tx.x;
    vec3 q = p + ng * (u_bias.w * texel0 * sqrt(max(1.0 - cos_l * cos_l, 0.0)));
    c = u_map2d_matrix[m] * vec4(q, 1.0);
#endif
    // Nothing casts between a perspective map's light and its near plane (the nearest caster),
    // nor behind the light, where a point light fitted by a frustum around its casters
    // (plan.fit.caster_cone) still shines: the divide below would fold such points into the map.
    if (persp && c.z <= 0.0) return 1.0;
    float inv_w = persp ? 1.0 / c.w : 1.0;
    vec2 uv = persp ? c.xy * inv_w : c.xy;
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return 1.0;
    float t = c.z;
    // Solve (cx.xy; cy.xy) (a, b) = (cx, cy).depth for the plane's coefficients. A receiver
    // seen edge-on by the camera makes the system singular: its tangent goes to the clamp.
    vec2 dd = persp ? vec2(cx.z, cy.z) * z.z : vec2(cx.z, cy.z);  // w = near + t span
    vec2 ab = vec2(dd.x * cy.y - cx.y * dd.y, cx.x * dd.y - dd.x * cy.x)
        * (1.0 / (cx.x * cy.y - cx.y * cy.x));
    // The plane's tangent to the light along each map axis (world depth over world texel), held
    // to PLANE_SLOPE_MAX; NaN (a degenerate triangle) counts as flat. Orthographic: the depth
    // changes by (a, b) / size per texel, in t units; perspective: by
    // (a, b) w^2 / ((w - (a, b) . uv) size span) at the lookup point.
    vec2 tan_axes = ab * k.xy;
    if (persp) tan_axes *= c.w / (c.w - dot(ab, c.xy));
    tan_axes = clamp(tan_axes, -PLANE_SLOPE_MAX, PLANE_SLOPE_MAX);
    tan_axes = mix(tan_axes, vec2(0.0), isnan(tan_axes));
    // The texel's size in stored depth (t units), which bias_world scales.
    float texel_t = persp ? z.x * c.w : z.x;
    Plane pl;
    pl.ref = t - bias_world(texel_t, length(tan_axes)) - z.y;
    pl.slope = tan_axes * (persp ? k.zw * c.w : k.zw);
    pl.persp = persp ? -tan_axes * k.zw * z.z : vec2(0.0);
    return shadow_2d(map, uv, pl, size);
}

// Map m's visibility through one case per slot (FOR_EACH_SLOT, from Python): every array index
// is a constant, as dynamic indexing of sampler arrays is where drivers differ. The cases past
// NUM_MAPS_2D are never taken and compile away; MAP2D_SLOT keeps their indices in range.
#define MAP2D_SLOT(K) min(K, NUM_MAPS_2D - 1)
#define MAP2D_CASE(K) if (K < NUM_MAPS_2D && m == K) return visibility_2d_from(u_map2d[MAP2D_SLOT(K)], v_map2d[MAP2D_SLOT(K)], d.dx[MAP2D_SLOT(K)], d.dy[MAP2D_SLOT(K)], MAP2D_SLOT(K), MAP2D_PERSP[MAP2D_SLOT(K)] != 0, p, ng, cos_l);
float visibility_2d(int m, Map2dDerivatives d, vec3 p, vec3 ng, float cos_l) {
    FOR_EACH_SLOT(MAP2D_CASE)
    return 1.0;
}
#endif
