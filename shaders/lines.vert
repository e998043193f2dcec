#version 330 core
layout(location = 0) in vec3 aPosition;
layout(location = 2) in float aScalar;  // a property's value (curves coloured by it)
uniform mat4 uView;
uniform mat4 uProjection;
out float vScalar;
void main() {
  vScalar = aScalar;
  gl_Position = uProjection * (uView * vec4(aPosition, 1.0));
}
