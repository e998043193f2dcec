// #version and lighting.glsl are prepended at load time.
in vec3 vViewPos;
in vec3 vNormal;
in float vScalar;
in vec4 vColor;
uniform int uUseScalar;
uniform float uScalarMin;
uniform float uScalarMax;
uniform sampler2D uColorMap;
uniform vec3 uBackColor;
uniform int uTwoSided;
uniform float uSpecular;
uniform int uFlat;
out vec4 fragColor;
void main() {
  // Flat: each polygon's own plane (a control mesh shown as the facets it is), from the
  // screen derivatives of the position, which face the viewer on either side.
  vec3 n = uFlat != 0 ? normalize(cross(dFdx(vViewPos), dFdy(vViewPos))) : normalize(vNormal);
  vec3 albedo = vColor.rgb;
  if (uUseScalar != 0) {
    float t = clamp((vScalar - uScalarMin) / (uScalarMax - uScalarMin), 0.0, 1.0);
    albedo = texture(uColorMap, vec2(t, 0.5)).rgb;
  }
  if (!gl_FrontFacing) {
    if (uFlat == 0) n = -n;
    // Open surfaces show their inside in a different tint, unless coloured by a scalar.
    if (uTwoSided != 0 && uUseScalar == 0) albedo = uBackColor;
  }
  fragColor = vec4(shade(albedo, n, vViewPos, uSpecular), vColor.a);
}
