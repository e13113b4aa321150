#version 330
in vec3 v_position;
in vec3 v_normal;
in vec2 v_uv;
layout(location = 0) out vec4 out_position;  // xyz world mm, w = 1 where the mesh covers the pixel
layout(location = 1) out vec4 out_normal;    // xyz unit normal (interpolated)
layout(location = 2) out vec4 out_uv;        // xy content uv

void main() {
    out_position = vec4(v_position, 1.0);
    out_normal = vec4(normalize(v_normal), 0.0);
    out_uv = vec4(v_uv, 0.0, 0.0);
}
