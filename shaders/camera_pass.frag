#version 410 core
// Camera pass: base colour x (ambient + sum over lights of visibility x (diffuse + specular)).
// Ambient is never shadowed and a shadowed point gets no specular (visibility scales both).
//
// Variant defines: NUM_LIGHTS, NUM_MAPS_2D, NUM_MAPS_CUBE, HAS_SPOT, HAS_POSITIONAL, HAS_UV,
// HAS_COLOR, ALPHA_MASK, OUT_VISIBILITY (number of RGBA visibility targets), ENCODING,
// FILTER_PCF, PCF_RADIUS, HW_PCF, NORMAL_OFFSET.
#define LIGHT_DIRECTIONAL 0
#define LIGHT_SPOT 1
#define LIGHT_POINT 2

in vec3 v_world;
in vec3 v_normal;
#if HAS_UV
in vec2 v_uv;
uniform sampler2D u_base_texture;
#endif
#if HAS_COLOR
in vec4 v_color;
#endif

uniform vec4 u_base_color;
#if ALPHA_MASK
uniform float u_alpha_cutoff;
#endif
uniform vec3 u_ambient;
uniform vec3 u_camera_position;
uniform float u_specular;
uniform float u_shininess;

#if NUM_LIGHTS > 0
// The light set is part of the variant (LIGHT_TYPES, LIGHT_MAPS are comma-separated lists): with
// constant types and map slots the unrolled loop keeps only each light's own code path.
const int LIGHT_TYPE[NUM_LIGHTS] = int[NUM_LIGHTS](LIGHT_TYPES);
// Map slot per light: >= 0 2D map; <= -2 cube map -(m + 2); -1 none.
const int LIGHT_MAP[NUM_LIGHTS] = int[NUM_LIGHTS](LIGHT_MAPS);
uniform vec3 u_light_position[NUM_LIGHTS];
uniform vec3 u_light_direction[NUM_LIGHTS];  // the way the light travels
uniform vec3 u_light_radiance[NUM_LIGHTS];   // colour x intensity
#if HAS_SPOT
uniform vec2 u_light_cone[NUM_LIGHTS];       // cos(outer), cos(inner)
#endif
#if HAS_POSITIONAL
uniform float u_light_range[NUM_LIGHTS];     // 0: unlimited
#endif
#endif

#if NUM_MAPS_2D > 0 || NUM_MAPS_CUBE > 0
uniform int u_receive_shadow;
uniform vec4 u_bias;         // constant, slope, slope max, normal offset (texels)
uniform float u_bias_steps;  // quantisation bias in steps of the encoding
#endif
#if NUM_MAPS_2D > 0
in vec4 v_map2d[NUM_MAPS_2D];
uniform MAP2D u_map2d[NUM_MAPS_2D];
uniform mat4 u_map2d_matrix[NUM_MAPS_2D];  // world -> biased light clip (normal offset)
uniform mat4 u_map2d_view[NUM_MAPS_2D];    // world -> light view (receiver-plane PCF)
uniform vec4 u_map2d_range[NUM_MAPS_2D];   // near, far, unused, map size
// World size of a texel at light depth d: x + y * d (orthographic: y = 0; perspective: x = 0).
uniform vec2 u_map2d_texel[NUM_MAPS_2D];
#endif
#if NUM_MAPS_CUBE > 0
uniform MAPCUBE u_mapcube[NUM_MAPS_CUBE];
uniform vec3 u_mapcube_position[NUM_MAPS_CUBE];
uniform vec3 u_mapcube_range[NUM_MAPS_CUBE];  // near, far, map size
#endif

layout(location = 0) out vec4 o_color;
#if OUT_VISIBILITY > 0
layout(location = 1) out vec4 o_visibility0;
#endif
#if OUT_VISIBILITY > 1
layout(location = 2) out vec4 o_visibility1;
#endif

vec3 srgb_to_linear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(0.04045, c));
}

vec3 linear_to_srgb(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
}

#if NUM_MAPS_2D > 0 || NUM_MAPS_CUBE > 0
// Depth bias in world units at a receiver whose texel has world size `texel`, for a surface at
// angle acos(cos_l) to the light: a texel-sized constant plus the depth change across a texel.
float bias_world(float texel, float tan_l) {
    float slope = min(tan_l, u_bias.z);
#if HW_PCF
    slope *= 2.0;  // bilinear compare reaches one texel further
#endif
    return texel * (u_bias.x + u_bias.y * slope);
}
#endif

#if NUM_MAPS_2D > 0
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
    float ref = t - bias_world(texel, tan_l) / span - u_bias_steps * ENC_STEP;
#if PCF_RADIUS > 0
    // Depth of the receiver's plane along a tap moved by one texel (dx, dy) across the map:
    // orthographic rays change it by (n.x dx + n.y dy) / n.z, perspective rays through the light
    // by -depth (n.x dx + n.y dy) / (n . p) (both to first order).
    vec3 nl = mat3(u_map2d_view[m]) * ng;
    vec2 slope = nl.xy / max(nl.z, 1e-6);
    if (persp > 0.0) {
        vec3 pv = (u_map2d_view[m] * vec4(p, 1.0)).xyz;
        slope = -c.w * nl.xy / min(dot(nl, pv), -1e-30);
    }
    vec2 dref = clamp(slope, -u_bias.z, u_bias.z) * (texel / span);
#else
    vec2 dref = vec2(0.0);
#endif
    return shadow_2d(map, uv, ref, dref, range.w);
}

// Constant indices only: dynamic indexing of sampler arrays is where drivers differ.
#define MAP2D_CASE(K) if (m == K) return visibility_2d_from(u_map2d[K], v_map2d[K], K, p, ng, cos_l, tan_l);
float visibility_2d(int m, vec3 p, vec3 ng, float cos_l, float tan_l) {
#if NUM_MAPS_2D > 0
    MAP2D_CASE(0)
#endif
#if NUM_MAPS_2D > 1
    MAP2D_CASE(1)
#endif
#if NUM_MAPS_2D > 2
    MAP2D_CASE(2)
#endif
#if NUM_MAPS_2D > 3
    MAP2D_CASE(3)
#endif
#if NUM_MAPS_2D > 4
    MAP2D_CASE(4)
#endif
#if NUM_MAPS_2D > 5
    MAP2D_CASE(5)
#endif
#if NUM_MAPS_2D > 6
    MAP2D_CASE(6)
#endif
#if NUM_MAPS_2D > 7
    MAP2D_CASE(7)
#endif
    return 1.0;
}
#endif

#if NUM_MAPS_CUBE > 0
float visibility_cube(int m, vec3 p, vec3 ng, float cos_l, float tan_l) {
    vec3 range = u_mapcube_range[m];
    vec3 d = p - u_mapcube_position[m];
    vec3 a = abs(d);
    float depth = max(a.x, max(a.y, a.z));
    float texel = 2.0 * depth / range.z;  // 90-degree faces
#if NORMAL_OFFSET
    vec3 q = p + ng * (u_bias.w * texel * sqrt(max(1.0 - cos_l * cos_l, 0.0)));
    d = q - u_mapcube_position[m];
    a = abs(d);
    depth = max(a.x, max(a.y, a.z));
#endif
    // The face's two lateral axes.
    vec3 u;
    vec3 v;
    if (a.x >= a.y && a.x >= a.z) {
        u = vec3(0.0, 1.0, 0.0); v = vec3(0.0, 0.0, 1.0);
    } else if (a.y >= a.z) {
        u = vec3(1.0, 0.0, 0.0); v = vec3(0.0, 0.0, 1.0);
    } else {
        u = vec3(1.0, 0.0, 0.0); v = vec3(0.0, 1.0, 0.0);
    }
    float span = range.y - range.x;
    float t = (depth - range.x) / span;
    float ref = t - bias_world(texel, tan_l) / span - u_bias_steps * ENC_STEP;
#if PCF_RADIUS > 0
    // A tap moved by w across the face meets the receiver's plane at face depth
    // depth (n . d) / (n . (d + w)): to first order a change of -depth (n . w) / (n . d).
    vec2 slope = -depth * vec2(dot(ng, u), dot(ng, v)) / min(dot(ng, d), -1e-30);
    vec2 dref = clamp(slope, -u_bias.z, u_bias.z) * (texel / span);
#else
    vec2 dref = vec2(0.0);
#endif
#if NUM_MAPS_CUBE > 0
    if (m == 0) return shadow_cube(u_mapcube[0], d, ref, dref, u * texel, v * texel);
#endif
#if NUM_MAPS_CUBE > 1
    if (m == 1) return shadow_cube(u_mapcube[1], d, ref, dref, u * texel, v * texel);
#endif
#if NUM_MAPS_CUBE > 2
    if (m == 2) return shadow_cube(u_mapcube[2], d, ref, dref, u * texel, v * texel);
#endif
#if NUM_MAPS_CUBE > 3
    if (m == 3) return shadow_cube(u_mapcube[3], d, ref, dref, u * texel, v * texel);
#endif
#if NUM_MAPS_CUBE > 4
    if (m == 4) return shadow_cube(u_mapcube[4], d, ref, dref, u * texel, v * texel);
#endif
#if NUM_MAPS_CUBE > 5
    if (m == 5) return shadow_cube(u_mapcube[5], d, ref, dref, u * texel, v * texel);
#endif
#if NUM_MAPS_CUBE > 6
    if (m == 6) return shadow_cube(u_mapcube[6], d, ref, dref, u * texel, v * texel);
#endif
#if NUM_MAPS_CUBE > 7
    if (m == 7) return shadow_cube(u_mapcube[7], d, ref, dref, u * texel, v * texel);
#endif
    return 1.0;
}
#endif

void main() {
    vec4 base = u_base_color;
#if HAS_UV
    vec4 tex = texture(u_base_texture, v_uv);
    base *= vec4(srgb_to_linear(tex.rgb), tex.a);
#endif
#if HAS_COLOR
    base *= v_color;
#endif
#if ALPHA_MASK
#if HAS_UV
    // The cut-out is tested at full resolution so its outline does not erode with distance.
    float coverage = base.a / max(tex.a, 1e-6) * textureLod(u_base_texture, v_uv, 0.0).a;
#else
    float coverage = base.a;
#endif
    if (coverage < u_alpha_cutoff) discard;
#endif
    vec3 p = v_world;
    vec3 to_eye = normalize(u_camera_position - p);
    vec3 n = normalize(v_normal);
    if (dot(n, to_eye) < 0.0) n = -n;  // light the side that is seen
    // Geometric normal, facing the camera: the true slope of the surface for the bias.
    vec3 ng = cross(dFdx(p), dFdy(p));
    float ng_len = length(ng);
    ng = ng_len > 0.0 ? ng / ng_len : n;
    if (dot(ng, to_eye) < 0.0) ng = -ng;

    vec3 color = u_ambient * base.rgb;
    float vis[8] = float[8](1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0);
#if NUM_LIGHTS > 0
    for (int i = 0; i < NUM_LIGHTS; ++i) {
        vec3 l = -u_light_direction[i];
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
        float shadow = 1.0;
#if NUM_MAPS_2D > 0 || NUM_MAPS_CUBE > 0
        int m = LIGHT_MAP[i];
        // Outside a spot's cone nothing is lit: no lookup, and the visibility reads 1 there
        // whether or not the plan gave this light a map.
        if (m != -1 && u_receive_shadow != 0 && atten > 0.0) {
            // The side of the surface that faces this light, for the normal offset and the slope.
            vec3 ngl = dot(ng, l) < 0.0 ? -ng : ng;
            float cos_l = max(dot(ngl, l), 1e-4);
            float tan_l = sqrt(max(1.0 - cos_l * cos_l, 0.0)) / cos_l;
#if NUM_MAPS_2D > 0
            if (m >= 0) shadow = visibility_2d(m, p, ngl, cos_l, tan_l);
#endif
#if NUM_MAPS_CUBE > 0
            if (m <= -2) shadow = visibility_cube(-m - 2, p, ngl, cos_l, tan_l);
#endif
        }
#endif
        vis[i] = shadow;
        float diffuse = max(dot(n, l), 0.0);
        vec3 h = normalize(l + to_eye);
        float spec = diffuse > 0.0 ? u_specular * pow(max(dot(n, h), 0.0), u_shininess) : 0.0;
        color += shadow * atten * u_light_radiance[i] * (diffuse * base.rgb + spec);
    }
#endif
    o_color = vec4(linear_to_srgb(color), base.a);
#if OUT_VISIBILITY > 0
    o_visibility0 = vec4(vis[0], vis[1], vis[2], vis[3]);
#endif
#if OUT_VISIBILITY > 1
    o_visibility1 = vec4(vis[4], vis[5], vis[6], vis[7]);
#endif
}
