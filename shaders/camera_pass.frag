#version 410 core
// Camera pass: base colour x (ambient + sum over lights of visibility x (diffuse + specular)).
// Ambient is never shadowed and a shadowed point gets no specular (visibility scales both).
//
// Variant defines and their defaults; renderer/passes/camera_pass.py sets them per draw.
#define NUM_LIGHTS 0        // lights shaded, at most MAX_LIGHTS
#define LIGHT_TYPES         // a LIGHT_* id per light, comma-separated
#define LIGHT_MAPS_2D       // each light's slot among the 2D maps (-1: none), comma-separated
#define MAP2D_PERSPECTIVE   // each 2D map's projection (1: perspective, 0: orthographic), comma-separated
#define LIGHT_MAPS_CUBE     // each light's slot among the cube maps (-1: none), comma-separated
#define LIGHT_MAPS_CSM      // each light's slot among the cascaded maps (-1: none), comma-separated
#define LIGHT_CASCADES      // each light's number of cascades (0: not cascaded), comma-separated
#define NUM_MAPS_2D 0
#define NUM_MAPS_CUBE 0
#define NUM_MAPS_CSM 0      // cascaded directional lights (one array texture each)
#define CASCADE_TINT 0      // tint the colour by the cascade read (debug)
#define HAS_SPOT 0          // uniforms of spot cones
#define HAS_POSITIONAL 0    // uniforms of light positions and ranges
#define HAS_UV 0            // base colour texture
#define HAS_COLOR 0         // vertex colours
#define ALPHA_MASK 0        // alpha cut-out
#define UNLIT 0             // KHR_materials_unlit: the colour is the base colour (visibility still out)
#define OUT_VISIBILITY 0    // RGBA visibility targets, four lights each
#define ENCODING ENC_DEPTH  // how the maps store depth
#define FILTER_PCF 0        // the PCF loop (of PCF_RADIUS taps either side)
#define PCF_RADIUS 0
#define NORMAL_OFFSET 0     // lookups moved along the normal
#define DEPTH_ONLY 0        // the depth alone is output: the cut-out's discard, no shading
#define NO_COLOR 0          // no colour output: the lookups for the visibility, no shading

#include "chunks/lighting.glsl"
#include "chunks/shadow_2d.glsl"
#include "chunks/shadow_cube.glsl"
#include "chunks/shadow_csm.glsl"

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
// The eye (w = 1); for an orthographic camera the direction toward the viewer (w = 0):
// to_eye = normalize(xyz - p * w) either way.
uniform vec4 u_camera_eye;
uniform float u_specular;
uniform float u_shininess;

#if NUM_LIGHTS > 0
// The map slots are part of the variant too: the unrolled loop keeps only the lookups of the
// lights that have a map.
const int LIGHT_MAP_2D[NUM_LIGHTS] = int[NUM_LIGHTS](LIGHT_MAPS_2D);
const int LIGHT_MAP_CUBE[NUM_LIGHTS] = int[NUM_LIGHTS](LIGHT_MAPS_CUBE);
#if NUM_MAPS_CSM > 0
const int LIGHT_MAP_CSM[NUM_LIGHTS] = int[NUM_LIGHTS](LIGHT_MAPS_CSM);
const int LIGHT_CASCADE[NUM_LIGHTS] = int[NUM_LIGHTS](LIGHT_CASCADES);
#endif
#endif
#if NUM_MAPS_2D > 0 || NUM_MAPS_CUBE > 0 || NUM_MAPS_CSM > 0
uniform int u_receive_shadow;
#endif

// Visibility per light, padded to whole RGBA targets.
const int VIS_SIZE = 4 * ((MAX_LIGHTS + 3) / 4);

layout(location = 0) out vec4 o_color;
#if OUT_VISIBILITY > 0
layout(location = 1) out vec4 o_visibility[OUT_VISIBILITY];
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
    vec3 p = v_world;
    vec3 to_eye = normalize(u_camera_eye.xyz - p * u_camera_eye.w);
    vec3 n = normalize(v_normal);
    if (dot(n, to_eye) < 0.0) n = -n;  // light the side that is seen
    // Geometric normal, facing the camera: the true slope of the surface for the bias and the
    // receiver plane of cube and cascaded maps, and the normal offset's direction. 2D maps take
    // their plane from their own coordinates' derivatives; where nothing else reads this, the
    // compiler drops it.
    vec3 ng = cross(dFdx(p), dFdy(p));
    float ng_len = length(ng);
    ng = ng_len > 0.0 ? ng / ng_len : n;
    if (dot(ng, to_eye) < 0.0) ng = -ng;

    vec3 color = u_ambient * base.rgb;
#if NUM_MAPS_2D > 0
    Map2dDerivatives map2d = map2d_derivatives();  // here, in uniform control flow
#endif
    // The cut-out's discard comes after every derivative: a quad's derivatives are undefined
    // once one of its fragments is discarded (NVIDIA's are garbage there, which drew false
    // shadow along every cut-out's outline; llvmpipe's happen to stay right).
#if ALPHA_MASK
#if HAS_UV
    // The cut-out is tested at full resolution so its outline does not erode with distance.
    float coverage = base.a / max(tex.a, 1e-6) * textureLod(u_base_texture, v_uv, 0.0).a;
#else
    float coverage = base.a;
#endif
    if (coverage < u_alpha_cutoff) discard;
#endif
#if DEPTH_ONLY
    o_color = vec4(0.0);  // not written (the colour mask is off): the depth test's write counts
    return;
#endif
    float vis[VIS_SIZE];
    for (int k = 0; k < VIS_SIZE; ++k) vis[k] = 1.0;
#if NUM_MAPS_CSM > 0
    float view_z = dot(vec4(p, 1.0), u_camera_forward);
    int cascade_read = -1;  // the cascade the first cascaded light read (CASCADE_TINT)
#endif
#if NUM_LIGHTS > 0
    for (int i = 0; i < NUM_LIGHTS; ++i) {
        vec3 l;
        float atten = light_attenuation(i, p, l);
        float shadow = 1.0;
#if NUM_MAPS_2D > 0 || NUM_MAPS_CUBE > 0 || NUM_MAPS_CSM > 0
        int m2 = LIGHT_MAP_2D[i];
        int mc = LIGHT_MAP_CUBE[i];
#if NUM_MAPS_CSM > 0
        int ms = LIGHT_MAP_CSM[i];
#else
        int ms = -1;
#endif
        // Outside a spot's cone nothing is lit: no lookup, and the visibility reads 1 there
        // whether or not the plan gave this light a map.
        if ((m2 != -1 || mc != -1 || ms != -1) && u_receive_shadow != 0 && atten > 0.0) {
            // The side of the surface that faces this light, for the normal offset and the slope.
            vec3 ngl = dot(ng, l) < 0.0 ? -ng : ng;
            float cos_l = max(dot(ngl, l), 1e-4);
            float tan_l = sqrt(max(1.0 - cos_l * cos_l, 0.0)) / cos_l;
#if NUM_MAPS_2D > 0
            if (m2 != -1) shadow = visibility_2d(m2, map2d, p, ngl, cos_l);
#endif
#if NUM_MAPS_CUBE > 0
            if (mc != -1) shadow = visibility_cube(mc, p, ngl, cos_l, tan_l);
#endif
#if NUM_MAPS_CSM > 0
            if (ms != -1) {
                int chosen;
                shadow = visibility_csm(ms, LIGHT_CASCADE[i], view_z, p, ngl, cos_l, tan_l,
                                        chosen);
                if (cascade_read < 0) cascade_read = chosen;
            }
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
#if CASCADE_TINT && NUM_MAPS_CSM > 0
    // Red, green, blue, yellow from the nearest cascade; untinted where no cascade was read.
    const vec3 TINT[4] = vec3[4](vec3(1.0, 0.55, 0.55), vec3(0.55, 1.0, 0.55),
                                 vec3(0.55, 0.65, 1.0), vec3(1.0, 1.0, 0.45));
    if (cascade_read >= 0) color *= TINT[cascade_read % 4];
#endif
#if UNLIT
    // Lighting, shadows included, is already in an unlit surface's colour; without visibility
    // outputs the compiler drops the lighting above.
    color = base.rgb;
#endif
#if NO_COLOR
    o_color = vec4(0.0);  // not written (its colour mask is off); the shading compiles away
#else
    o_color = vec4(linear_to_srgb(color), base.a);
#endif
#if OUT_VISIBILITY > 0
    for (int k = 0; k < OUT_VISIBILITY; ++k) {
        o_visibility[k] = vec4(vis[4 * k], vis[4 * k + 1], vis[4 * k + 2], vis[4 * k + 3]);
    }
#endif
}
