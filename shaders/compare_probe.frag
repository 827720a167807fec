#version 410 core
// Probe of chunks/shadow_lookup.glsl: one output pixel per query. Each query texel holds
// (u, v, ref, unused) or, with PLANE, (u, v, ref, dref along u) and dref along v from
// u_dref_v; the result is shadow_2d() against the bound map.
#define ENCODING ENC_DEPTH
#define FILTER_PCF 0
#define PCF_RADIUS 0

#include "chunks/shadow_lookup.glsl"

uniform MAP2D u_map;
uniform sampler2D u_queries;
uniform float u_map_size;
uniform float u_dref_v;
layout(location = 0) out vec4 o_value;

void main() {
    vec4 q = texelFetch(u_queries, ivec2(gl_FragCoord.xy), 0);
    o_value = vec4(shadow_2d(u_map, q.xy, Plane(q.z, vec2(q.w, u_dref_v), vec2(0.0)), u_map_size), 0.0, 0.0, 1.0);
}
