// GLSL 1.40 (OpenGL 3.1), 3.30 and GLSL ES 3.00 (OpenGL ES 3): the renderer puts the #version line first (shaders.py).
// One triangle that covers the whole viewport; no vertex buffer (positions from gl_VertexID).
void main() {
    vec2 p = vec2(float((gl_VertexID & 1) << 2), float((gl_VertexID & 2) << 1)) - 1.0;
    gl_Position = vec4(p, 0.0, 1.0);
}
