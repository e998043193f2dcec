// Shared by surface.frag and points.frag (prepended at load time).
// Blinn-Phong with two directional lights in view space (a key light from the upper left
// and a fill light from the right), a hemispherical ambient term and a soft rim. Lighting
// is computed in linear RGB; colours come in and go out sRGB-encoded.
vec3 toLinear(vec3 c) { return pow(c, vec3(2.2)); }
vec3 toSrgb(vec3 c) { return pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)); }

vec3 shade(vec3 albedoSrgb, vec3 n, vec3 viewPos, float specularStrength) {
  vec3 albedo = toLinear(albedoSrgb);
  vec3 v = normalize(-viewPos);
  const vec3 keyDir = normalize(vec3(-0.45, 0.65, 0.62));
  const vec3 fillDir = normalize(vec3(0.70, 0.05, 0.45));
  const float keyIntensity = 0.82;
  const float fillIntensity = 0.32;
  float hemi = 0.5 + 0.5 * n.y;
  vec3 ambient = mix(vec3(0.10, 0.10, 0.12), vec3(0.24, 0.25, 0.28), hemi);
  float keyDiffuse = max(dot(n, keyDir), 0.0);
  float fillDiffuse = max(dot(n, fillDir), 0.0);
  vec3 keyHalf = normalize(keyDir + v);
  vec3 fillHalf = normalize(fillDir + v);
  float keySpec = pow(max(dot(n, keyHalf), 0.0), 48.0) * keyDiffuse;
  float fillSpec = pow(max(dot(n, fillHalf), 0.0), 48.0) * fillDiffuse;
  float rim = pow(1.0 - max(dot(n, v), 0.0), 3.0) * 0.12;
  vec3 color = albedo * (ambient + keyIntensity * keyDiffuse + fillIntensity * fillDiffuse) +
               specularStrength * (keyIntensity * keySpec + fillIntensity * fillSpec) +
               rim * vec3(0.9, 0.93, 1.0);
  return toSrgb(color);
}
