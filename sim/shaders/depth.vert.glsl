#version 330
// Depth map from a projector: distance along its optical axis, for shadow tests.
uniform mat4 mvp;           // world mm -> clip
uniform vec4 zrow;          // third row of [R | t]: device depth of a world point
in vec3 in_position;
out float v_depth;

void main() {
    v_depth = dot(zrow, vec4(in_position, 1.0));
    gl_Position = mvp * vec4(in_position, 1.0);
}
