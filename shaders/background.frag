#version 330 core
// Vertical gradient with a faint vignette, in sRGB.
in vec2 vUv;
uniform vec3 uTop;
uniform vec3 uBottom;
uniform int uGradient;
out vec4 fragColor;
void main() {
  if (uGradient == 0) {
    fragColor = vec4(uTop, 1.0);
    return;
  }
  float t = smoothstep(0.0, 1.0, vUv.y);
  vec3 color = mix(uBottom, uTop, t);
  vec2 c = vUv - vec2(0.5, 0.55);
  color *= 1.0 - 0.10 * dot(c, c);
  fragColor = vec4(color, 1.0);
}
