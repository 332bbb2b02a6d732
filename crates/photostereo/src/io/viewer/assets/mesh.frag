#version 300 es
// The relighting of the image view on the mesh: the light is fixed to the object (camera frame
// of the capture), the specular half vector uses the actual viewing direction.
precision highp float;
uniform vec3 uLight;
uniform vec3 uEye;       // camera position, object frame
uniform float uGain;
uniform float uSpec;
uniform float uShine;
uniform float uAmbient;
uniform bool uSrgb;
in vec3 vPos;
in vec3 vNormal;
in vec3 vAlbedo;
out vec4 outColor;

float srgb(float v) {
  v = clamp(v, 0.0, 1.0);
  return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

void main() {
  vec3 n = normalize(vNormal);
  vec3 v = normalize(uEye - vPos);
  if (!gl_FrontFacing) {
    outColor = vec4(0.18, 0.18, 0.2, 1.0);
    return;
  }
  float d = max(dot(n, uLight), 0.0);
  vec3 h = normalize(uLight + v);
  float s = d > 0.0 ? pow(max(dot(n, h), 0.0), uShine) : 0.0;
  vec3 lin = clamp(uGain * (vAlbedo * (uAmbient + (1.0 - uAmbient) * d) + uSpec * s), 0.0, 1.0);
  outColor = vec4(uSrgb ? vec3(srgb(lin.r), srgb(lin.g), srgb(lin.b)) : lin, 1.0);
}
