#version 330
// Camera G-buffer of a mesh: world position, normal and texture coordinates per pixel.
uniform mat4 mvp;           // world mm -> clip (see sim.geometry.Pinhole.gl_projection)
in vec3 in_position;        // world mm
in vec3 in_normal;          // unit vertex normal
in vec2 in_uv;              // content uv, (0, 0) top-left
out vec3 v_position;
out vec3 v_normal;
out vec2 v_uv;

void main() {
    v_position = in_position;
    v_normal = in_normal;
    v_uv = in_uv;
    gl_Position = mvp * vec4(in_position, 1.0);
}
