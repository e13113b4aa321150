#version 330
in vec3 v_position;
flat in float v_kind;
out vec4 out_position;   // xyz world mm (perspective-correct at the pixel centre), w = surface kind

void main() {
    out_position = vec4(v_position, v_kind);
}
