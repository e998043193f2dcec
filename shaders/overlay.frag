#version 330 core
in vec2 vUv;
uniform sampler2D uTexture;
uniform float uOpacity;  // scales the texture's alpha (a faded legend)
out vec4 fragColor;
void main() {
  vec4 c = texture(uTexture, vUv);
  fragColor = vec4(c.rgb, c.a * uOpacity);
}
