#version 330 core
// Core profile has no wide lines: each segment becomes a screen-space quad uWidth pixels
// wide with square caps, pulled slightly towards the eye so lines on the surface win the
// depth test against it.
layout(lines) in;
layout(triangle_strip, max_vertices = 4) out;
uniform vec2 uViewport;
uniform float uWidth;
uniform float uDepthBias;
in float vScalar[];
out float gScalar;
void emitCorner(vec4 p, vec2 offsetPixels, float scalar) {
  vec2 ndcOffset = offsetPixels / (0.5 * uViewport);
  gl_Position = vec4(p.xy + ndcOffset * p.w, p.z - uDepthBias * p.w, p.w);
  gScalar = scalar;
  EmitVertex();
}
void main() {
  vec4 p0 = gl_in[0].gl_Position;
  vec4 p1 = gl_in[1].gl_Position;
  if (p0.w <= 1e-6 || p1.w <= 1e-6) return;  // behind the eye
  vec2 s0 = p0.xy / p0.w * 0.5 * uViewport;
  vec2 s1 = p1.xy / p1.w * 0.5 * uViewport;
  vec2 d = s1 - s0;
  float len = length(d);
  d = len > 1e-6 ? d / len : vec2(1.0, 0.0);
  vec2 n = vec2(-d.y, d.x) * (0.5 * uWidth);
  vec2 e = d * (0.5 * uWidth);
  emitCorner(p0, -e + n, vScalar[0]);
  emitCorner(p0, -e - n, vScalar[0]);
  emitCorner(p1, e + n, vScalar[1]);
  emitCorner(p1, e - n, vScalar[1]);
  EndPrimitive();
}
