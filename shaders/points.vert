#version 330 core
// Sphere impostors: a point per sphere, with an optional per-point colour.
layout(location = 0) in vec3 aPosition;
layout(location = 1) in vec4 aColor;
uniform mat4 uView;
out vec3 gCenter;
out vec4 gColor;
void main() {
  gCenter = (uView * vec4(aPosition, 1.0)).xyz;
  gColor = aColor;
  gl_Position = vec4(gCenter, 1.0);
}
