#version 330
in float v_depth;
layout(location = 0) out float out_depth;    // mm along the device axis

void main() {
    out_depth = v_depth;
}
