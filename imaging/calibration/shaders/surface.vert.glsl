#version 330
// World position per camera pixel: the surface (mesh and table) seen through a pinhole camera.
uniform mat4 mvp;        // world mm -> clip (imaging.calibration.threed.gl_projection)
in vec3 in_position;     // world mm
in float in_kind;        // 1 = table plane, 2 = mesh
out vec3 v_position;
flat out float v_kind;

void main() {
    v_position = in_position;
    v_kind = in_kind;
    gl_Position = mvp * vec4(in_position, 1.0);
}
