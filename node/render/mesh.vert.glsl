// GLSL 1.40 (OpenGL 3.1), 3.30 and GLSL ES 3.00 (OpenGL ES 3): the renderer puts the #version line first (shaders.py).
// Projection pose: world mm -> clip space. world_to_clip folds the 3x4 projection matrix P,
// the pixel -> NDC mapping (half-pixel offset, y flipped) and the near/far depth range.
uniform mat4 world_to_clip;

in vec3 in_position;  // world mm
in vec2 in_uv;        // (0, 0) top-left of the content, (1, 1) bottom-right

out vec2 uv;

void main() {
    gl_Position = world_to_clip * vec4(in_position, 1.0);
    uv = in_uv;  // perspective-correct interpolation (the default)
}
