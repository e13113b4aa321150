// GLSL 1.40 (OpenGL 3.1), 3.30 and GLSL ES 3.00 (OpenGL ES 3): the renderer puts the #version line first (shaders.py).
// Projection pose: sample the content at the mesh's UV, u * W - 0.5 and v * H - 0.5 in content pixels.
#include "pipeline.glsl"

in vec2 uv;
out vec4 colour;

void main() {
    colour = finish(sample_faded(uv * vec2(textureSize(content, 0)) - 0.5));
}
