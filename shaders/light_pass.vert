#version 410 core
// Light pass: transform into the light's view. Positions are relative to the scene's origin
// (see renderer.gpu), so float32 keeps its precision far from the world origin.
//
// Variant defines and their defaults; renderer/passes/light_pass.py sets them per draw.
#define ALPHA_TEST 0  // alpha cut-out casters: pass the texture coordinates on
#define LOC_UV 2      // attribute slots, as renderer/gl/resources.py lays them out
#define LOC_MODEL 2

layout(location = 0) in vec3 a_position;
#if ALPHA_TEST
layout(location = LOC_UV) in vec2 a_uv;
out vec2 v_uv;
#endif
layout(location = LOC_MODEL) in mat4 a_model;  // per instance

uniform mat4 u_light_view;
uniform mat4 u_light_proj;

out float v_light_depth;  // distance along the light's axis

void main() {
    vec4 view = u_light_view * (a_model * vec4(a_position, 1.0));
    v_light_depth = -view.z;
#if ALPHA_TEST
    v_uv = a_uv;
#endif
    gl_Position = u_light_proj * view;
}
