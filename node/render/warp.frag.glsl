// GLSL 1.40 (OpenGL 3.1), 3.30 and GLSL ES 3.00 (OpenGL ES 3): the renderer puts the #version line first (shaders.py).
// Homography pose: each projector pixel looks up the content through H^-1.
#include "pipeline.glsl"

// (gl_FragCoord.x, gl_FragCoord.y, 1) -> homogeneous content pixel coordinates. Built on
// the CPU as H^-1 @ F, where F turns GL window coordinates (fragment centres at +0.5,
// rows bottom-up) into OpenCV projector pixels; its sign makes w > 0 on the side of the
// horizon where the content lies.
uniform mat3 frag_to_content;

out vec4 colour;

void main() {
    vec3 q = frag_to_content * vec3(gl_FragCoord.xy, 1.0);
    vec3 value = q.z > 0.0 ? sample_faded(q.xy / q.z) : vec3(0.0);  // beyond the horizon: no content
    colour = finish(value);
}
