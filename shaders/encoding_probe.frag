#version 410 core
// Probe of chunks/depth_encoding.glsl. ENCODE 1: read t from an R32F texture, write
// encode_depth(t) to an RGBA8 target. ENCODE 0: read RGBA8 texels, write decode_depth() to an
// R32F target.
#define ENCODING ENC_RGBA8
#define ENCODE 1

#include "chunks/depth_encoding.glsl"

uniform sampler2D u_input;
layout(location = 0) out vec4 o_value;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
#if ENCODE
    o_value = encode_depth(texelFetch(u_input, texel, 0).r);
#else
    o_value = vec4(decode_depth(texelFetch(u_input, texel, 0)), 0.0, 0.0, 1.0);
#endif
}
