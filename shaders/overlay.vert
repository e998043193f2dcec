#version 330 core
// A textured rectangle in pixel coordinates (origin top left), e.g. the legend.
uniform vec4 uRect;  // x0, y0, x1, y1 in pixels
uniform vec2 uViewport;
out vec2 vUv;
void main() {
  vec2 corner = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1));
  vec2 pixel = mix(uRect.xy, uRect.zw, corner);
  vUv = corner;
  vec2 ndc = vec2(pixel.x / uViewport.x * 2.0 - 1.0, 1.0 - pixel.y / uViewport.y * 2.0);
  gl_Position = vec4(ndc, 0.0, 1.0);
}
