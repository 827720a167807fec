#version 410 core
// Camera pass: world position (relative to the scene's origin), normal, and the optional
// texture coordinates and vertex colours of the primitive.
//
// Variant defines and their defaults; renderer/passes/camera_pass.py sets them per draw. The
// attribute slots follow renderer/gl/resources.py: position 0, normal 1, then UV, colour and the
// instance matrix in the first free slots.
#define HAS_UV 0       // texture coordinates
#define HAS_COLOR 0    // vertex colours
#define NUM_MAPS_2D 0  // 2D shadow maps, whose coordinates are interpolated from here
#define LOC_UV 2
#define LOC_COLOR 2
#define LOC_MODEL 2

layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
#if HAS_UV
layout(location = LOC_UV) in vec2 a_uv;
out vec2 v_uv;
#endif
#if HAS_COLOR
layout(location = LOC_COLOR) in vec4 a_color;
out vec4 v_color;
#endif
layout(location = LOC_MODEL) in mat4 a_model;  // per instance

uniform mat4 u_view_proj;
#if NUM_MAPS_2D > 0
// Per 2D shadow map: world -> light clip with x, y and z mapped to [0, 1] (the documents' bias
// matrix), evaluated per vertex and interpolated rather than per fragment.
uniform mat4 u_map2d_matrix[NUM_MAPS_2D];
out vec4 v_map2d[NUM_MAPS_2D];
#endif

out vec3 v_world;
out vec3 v_normal;
// Every variant puts a vertex at the very same depth: the camera pass draws a receiver with
// shadow lookups inside its shadow's rectangle first, then again whole without them, where the
// strict depth test (GL_GREATER with reversed depth, else GL_LESS) keeps the first draw's
// pixels (renderer/plan/shadow_region.py).
invariant gl_Position;

void main() {
    vec4 world = a_model * vec4(a_position, 1.0);
    v_world = world.xyz;
    // Cofactor matrix = inverse transpose x determinant: correct under non-uniform scale
    // without a per-vertex inverse. Its sign is the determinant's, so under a mirroring matrix
    // (determinant < 0) it turns the normal inside out: multiply by that sign again.
    mat3 m = mat3(a_model);
    mat3 cof = mat3(cross(m[1], m[2]), cross(m[2], m[0]), cross(m[0], m[1]));
    v_normal = cof * a_normal * (dot(m[0], cof[0]) < 0.0 ? -1.0 : 1.0);
#if HAS_UV
    v_uv = a_uv;
#endif
#if HAS_COLOR
    v_color = a_color;
#endif
#if NUM_MAPS_2D > 0
    for (int m = 0; m < NUM_MAPS_2D; ++m) v_map2d[m] = u_map2d_matrix[m] * world;
#endif
    gl_Position = u_view_proj * world;
}
