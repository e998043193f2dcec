#version 330 core
// A view-aligned square in front of each sphere, large enough to cover its silhouette;
// the fragment shader ray-casts the sphere inside it.
layout(points) in;
layout(triangle_strip, max_vertices = 4) out;
in vec3 gCenter[];
in vec4 gColor[];
uniform mat4 uProjection;
uniform float uRadius;
out vec3 vViewPos;
flat out vec3 vCenter;
flat out vec4 vColor;
void main() {
  vec3 c = gCenter[0];
  if (c.z > -uRadius * 1.5) return;  // at or behind the eye
  // A square at the sphere's front, scaled so its projection covers the silhouette.
  float scale = 1.6;
  vec3 front = c + vec3(0.0, 0.0, uRadius);
  vec2 corners[4] = vec2[](vec2(-1.0, -1.0), vec2(1.0, -1.0), vec2(-1.0, 1.0), vec2(1.0, 1.0));
  for (int i = 0; i < 4; ++i) {
    vec3 p = front + vec3(corners[i] * uRadius * scale, 0.0);
    vViewPos = p;
    vCenter = c;
    vColor = gColor[0];
    gl_Position = uProjection * vec4(p, 1.0);
    EmitVertex();
  }
  EndPrimitive();
}
