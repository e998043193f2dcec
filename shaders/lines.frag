#version 330 core
in float gScalar;
uniform vec4 uColor;
// A curve coloured by a property, as the surface is (surface.frag): its value through the
// colour map over [uScalarMin, uScalarMax].
uniform int uUseScalar;
uniform float uScalarMin;
uniform float uScalarMax;
uniform sampler2D uColorMap;
out vec4 fragColor;
void main() {
  fragColor = uColor;
  if (uUseScalar != 0) {
    float t = clamp((gScalar - uScalarMin) / (uScalarMax - uScalarMin), 0.0, 1.0);
    fragColor = vec4(texture(uColorMap, vec2(t, 0.5)).rgb, uColor.a);
  }
}
