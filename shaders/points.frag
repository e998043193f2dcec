// #version and lighting.glsl are prepended at load time.
in vec3 vViewPos;
flat in vec3 vCenter;
flat in vec4 vColor;
uniform mat4 uProjection;
uniform float uRadius;
out vec4 fragColor;
void main() {
  // Ray from the eye (the view-space origin) through this fragment, against the sphere.
  vec3 dir = normalize(vViewPos);
  float b = dot(dir, vCenter);
  float c = dot(vCenter, vCenter) - uRadius * uRadius;
  float disc = b * b - c;
  if (disc < 0.0) discard;
  vec3 hit = dir * (b - sqrt(disc));
  vec3 n = (hit - vCenter) / uRadius;
  vec4 clip = uProjection * vec4(hit, 1.0);
  gl_FragDepth = 0.5 * (clip.z / clip.w) + 0.5;
  fragColor = vec4(shade(vColor.rgb, n, hit, 0.45), 1.0);
}
