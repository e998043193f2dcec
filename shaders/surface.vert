#version 330 core
// The surface: per-vertex position, normal and scalar (colour-map coordinate).
layout(location = 0) in vec3 aPosition;
layout(location = 1) in vec3 aNormal;
layout(location = 2) in float aScalar;
uniform mat4 uView;
uniform mat4 uProjection;
out vec3 vViewPos;
out vec3 vNormal;
out float vScalar;
out vec4 vColor;
uniform vec4 uColor;
void main() {
  vec4 viewPos = uView * vec4(aPosition, 1.0);
  vViewPos = viewPos.xyz;
  vNormal = mat3(uView) * aNormal;
  vScalar = aScalar;
  vColor = uColor;
  gl_Position = uProjection * viewPos;
}
