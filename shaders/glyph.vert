#version 330 core
// Instanced glyph meshes (cubes, spheres, arrow shafts and heads, torque rings): each
// instance has its own model matrix (columns in locations 3..6) and colour.
layout(location = 0) in vec3 aPosition;
layout(location = 1) in vec3 aNormal;
layout(location = 3) in vec4 aModel0;
layout(location = 4) in vec4 aModel1;
layout(location = 5) in vec4 aModel2;
layout(location = 6) in vec4 aModel3;
layout(location = 7) in vec4 aColor;
uniform mat4 uView;
uniform mat4 uProjection;
out vec3 vViewPos;
out vec3 vNormal;
out float vScalar;
out vec4 vColor;
void main() {
  mat4 model = mat4(aModel0, aModel1, aModel2, aModel3);
  vec4 viewPos = uView * model * vec4(aPosition, 1.0);
  // Inverse transpose: glyphs are scaled non-uniformly (arrow length vs thickness).
  mat3 normalMatrix = transpose(inverse(mat3(model)));
  vViewPos = viewPos.xyz;
  vNormal = mat3(uView) * (normalMatrix * aNormal);
  vScalar = 0.0;
  vColor = aColor;
  gl_Position = uProjection * viewPos;
}
