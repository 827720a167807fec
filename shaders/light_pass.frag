#version 410 core
// Light pass: store the linear light depth t = (depth - near) / (far - near) of the closest
// caster, packed into colour channels or written to the depth texture.
//
// Variant defines and their defaults; renderer/passes/light_pass.py sets them per draw.
#define ENCODING ENC_DEPTH  // how the map stores depth
#define ALPHA_TEST 0        // alpha cut-out casters
#define WRITE_DEPTH 0       // store the linear depth as the window depth (perspective lights)
#define POLYGON_OFFSET 0    // offset the stored depth (factor x slope + units x step)

#include "chunks/depth_encoding.glsl"

in float v_light_depth;
#if ALPHA_TEST
in vec2 v_uv;
uniform sampler2D u_alpha_texture;  // the base colour texture's alpha, level 0 (R8)
uniform float u_base_alpha;
uniform float u_alpha_cutoff;
#endif

uniform vec2 u_depth_range;  // near, far of the light's frustum

#if POLYGON_OFFSET
uniform vec2 u_polygon_offset;  // factor (x depth slope), units x the map's depth step
#endif

#if ENCODING != ENC_DEPTH
layout(location = 0) out vec4 o_depth;
#endif

void main() {
    float t = (v_light_depth - u_depth_range.x) / (u_depth_range.y - u_depth_range.x);
#if POLYGON_OFFSET
    t += u_polygon_offset.x * max(abs(dFdx(t)), abs(dFdy(t))) + u_polygon_offset.y;
#endif
#if ALPHA_TEST
    // After the derivatives, which a discarded fragment leaves undefined in its quad. Level 0
    // (the copy has no other): mipmaps would average thin cut-out features away at the light's
    // texel rate.
    if (u_base_alpha * textureLod(u_alpha_texture, v_uv, 0.0).r < u_alpha_cutoff) discard;
#endif
#if WRITE_DEPTH
    // Perspective lights: test and store linear depth rather than the hyperbolic window depth.
    gl_FragDepth = clamp(t, 0.0, 1.0);
#endif
#if ENCODING != ENC_DEPTH
    o_depth = encode_depth(t);
#endif
}
