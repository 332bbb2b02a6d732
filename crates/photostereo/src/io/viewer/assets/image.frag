#version 300 es
// The image layers. The page prepends "#define LAYER_<NAME>" after the version line.
// Tiles are fetched texel by texel (nearest): the pyramid level is chosen so that a texel covers
// one to two screen pixels. The relighting expression is the one of viewer/relight.rs.
precision highp float;
precision highp int;
precision highp usampler2D;

uniform highp usampler2D uN;  // normals, RGB16UI, (n + 1) / 2 * 65535, 0 outside
uniform highp usampler2D uA;  // albedo, RGB16UI, albedo / uAlbedoMax * 65535
uniform sampler2D uD;         // shaded depth, RGB8
uniform highp usampler2D uQ;  // (unusable count, flags), RG8UI
uniform highp sampler2D uR;   // (residual, error degrees), RG32F, -1 where missing
uniform highp usampler2D uS;  // one plane of packed light statuses, R8UI
uniform highp usampler2D uC;  // RTI planes, RGBA16UI, four a texel, layers stacked in y
uniform highp usampler2D uU;  // blurred normals, as uN
uniform highp sampler2D uG;   // (specular strength, roughness), RG32F, -1 where missing
uniform ivec2 uSize;          // tile size, texels

// The RTI layer (viewer/rti.rs): rti = uW0 + sum_q plane_q * uW[q] (times the chroma planes).
uniform int uPlanes;          // coefficient planes K
uniform bool uChroma;         // three chroma planes follow (PTM LRGB)
uniform float uLo[32];        // plane q = uLo[q] + code / 65535 * uSpan[q]
uniform float uSpan[32];
uniform vec3 uW[27];
uniform vec3 uW0;
uniform bool uPtm;
uniform int uFc;              // fitted channels
uniform float uB[6];          // PTM terms at the light (u^2, v^2, uv, u, v, 1)
uniform float uDGain;         // diffuse gain (1: off), PTM only
uniform float uSharp;         // unsharp-mask amount of the normals (0: off)
uniform int uGloss;           // 0: specular strength, 1: roughness

uniform vec3 uLight;          // unit, toward the light
uniform float uGain;          // 2^exposure
uniform float uSpec;
uniform float uShine;
uniform float uAmbient;
uniform float uWhite;
uniform float uAlbedoMax;
uniform bool uSrgb;
uniform int uShift;           // bit offset of the chosen light in the status plane
uniform float uMax;           // upper end of the colour bar
uniform vec3 uBg;

in vec2 vUV;
out vec4 outColor;

const uint FLAG_INSIDE = 1u;
const uint FLAG_UNRELIABLE = 2u;
const uint FLAG_FEWER = 8u;

vec3 colormap(float t) {
  vec3 s[9] = vec3[9](vec3(68.0, 1.0, 84.0), vec3(71.0, 44.0, 122.0), vec3(59.0, 81.0, 139.0),
    vec3(44.0, 113.0, 142.0), vec3(33.0, 144.0, 141.0), vec3(39.0, 173.0, 129.0),
    vec3(92.0, 200.0, 99.0), vec3(170.0, 220.0, 50.0), vec3(253.0, 231.0, 37.0));
  float x = clamp(t, 0.0, 1.0) * 8.0;
  int i = min(int(floor(x)), 7);
  float f = x - float(i);
  return (s[i] * (1.0 - f) + s[i + 1] * f) / 255.0;
}

float srgb(float v) {
  v = clamp(v, 0.0, 1.0);
  return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

vec3 encode(vec3 lin) {
  vec3 c = clamp(lin, 0.0, 1.0);
  return uSrgb ? vec3(srgb(c.r), srgb(c.g), srgb(c.b)) : c;
}

float rtiPlane(ivec2 t, int q) {
  uvec4 c = texelFetch(uC, ivec2(t.x, t.y + (q / 4) * uSize.y), 0);
  int k = q - (q / 4) * 4;
  uint v = k == 0 ? c.r : k == 1 ? c.g : k == 2 ? c.b : c.a;
  return uLo[q] + float(v) / 65535.0 * uSpan[q];
}

// Malzbender et al. 2001, section 5.2: the polynomial a with its curvature times g about p.
float ptmGained(float a[6], vec2 p, float g) {
  float a3 = (1.0 - g) * (2.0 * a[0] * p.x + a[2] * p.y) + a[3];
  float a4 = (1.0 - g) * (2.0 * a[1] * p.y + a[2] * p.x) + a[4];
  float a5 = (1.0 - g) * (a[0] * p.x * p.x + a[1] * p.y * p.y + a[2] * p.x * p.y)
    + (a[3] - a3) * p.x + (a[4] - a4) * p.y + a[5];
  return g * (a[0] * uB[0] + a[1] * uB[1] + a[2] * uB[2]) + a3 * uB[3] + a4 * uB[4] + a5 * uB[5];
}

vec2 ptmNormal(float a[6]) {
  float den = 4.0 * a[0] * a[1] - a[2] * a[2];
  if (den == 0.0) return vec2(0.0);
  vec2 p = vec2(a[2] * a[4] - 2.0 * a[1] * a[3], a[2] * a[3] - 2.0 * a[0] * a[4]) / den;
  float r = length(p);
  return r > 1.0 ? p / r : p;
}

vec3 rtiValue(ivec2 t) {
  vec3 v = uW0;
  if (uPtm && uDGain != 1.0) {
    float m[6];
    for (int j = 0; j < 6; j++) {
      m[j] = 0.0;
      for (int ch = 0; ch < uFc; ch++) m[j] += rtiPlane(t, ch * 6 + j);
      m[j] /= float(uFc);
    }
    vec2 p = ptmNormal(m);
    for (int ch = 0; ch < 3; ch++) {
      float a[6];
      int cc = min(ch, uFc - 1);
      for (int j = 0; j < 6; j++) a[j] = rtiPlane(t, cc * 6 + j);
      v[ch] = ptmGained(a, p, uDGain);
    }
  } else {
    for (int q = 0; q < uPlanes; q++) v += rtiPlane(t, q) * uW[q];
  }
  if (uChroma) v *= vec3(rtiPlane(t, uPlanes), rtiPlane(t, uPlanes + 1), rtiPlane(t, uPlanes + 2));
  return v;
}

void main() {
  ivec2 t = ivec2(min(floor(vUV * vec2(uSize)), vec2(uSize) - 1.0));
  vec3 c = uBg;
#if defined(LAYER_RELIGHT) || defined(LAYER_NORMALS) || defined(LAYER_ALBEDO) || defined(LAYER_RTI)
  uvec3 nc = texelFetch(uN, t, 0).rgb;
  bool inside = nc != uvec3(0u);
  vec3 n0 = vec3(nc) / 65535.0 * 2.0 - 1.0;
#else
  uint flags = texelFetch(uQ, t, 0).g;
  bool inside = (flags & FLAG_INSIDE) != 0u;
#endif
  if (inside) {
#if defined(LAYER_RELIGHT)
    vec3 n = normalize(n0);
    vec3 rho = vec3(texelFetch(uA, t, 0).rgb) / 65535.0 * uAlbedoMax;
    float d = max(dot(n, uLight), 0.0);
    vec3 h = normalize(uLight + vec3(0.0, 0.0, 1.0));
    float s = d > 0.0 ? pow(max(dot(n, h), 0.0), uShine) : 0.0;
    float shade = uAmbient + (1.0 - uAmbient) * d;
    c = encode(uGain * (rho / uWhite * shade + uSpec * s));
#elif defined(LAYER_RTI)
    vec3 n = normalize(n0);
    vec3 v = rtiValue(t);
    float d = max(dot(n, uLight), 0.0);
    vec3 h = normalize(uLight + vec3(0.0, 0.0, 1.0));
    float s = d > 0.0 ? pow(max(dot(n, h), 0.0), uShine) : 0.0;
    float sharp = 0.0;
    vec3 rho = vec3(0.0);
    if (uSharp != 0.0) {
      vec3 nb = vec3(texelFetch(uU, t, 0).rgb) / 65535.0 * 2.0 - 1.0;
      vec3 n2 = normalize(n + uSharp * (n - nb));
      sharp = max(dot(n2, uLight), 0.0) - d;
      rho = vec3(texelFetch(uA, t, 0).rgb) / 65535.0 * uAlbedoMax;
    }
    c = encode(uGain * (v + uSpec * s + rho / uWhite * sharp));
#elif defined(LAYER_NORMALS)
    c = (n0 + 1.0) * 0.5;
#elif defined(LAYER_ALBEDO)
    vec3 rho = vec3(texelFetch(uA, t, 0).rgb) / 65535.0 * uAlbedoMax;
    c = encode(uGain * rho / uWhite);
#elif defined(LAYER_DEPTH)
    c = texelFetch(uD, t, 0).rgb;
#elif defined(LAYER_UNRELIABLE)
    float r = texelFetch(uR, t, 0).r;
    float g = r >= 0.0 ? sqrt(clamp(r / uMax, 0.0, 1.0)) : 0.5;
    c = vec3(g);
    if ((flags & FLAG_UNRELIABLE) != 0u) c = mix(c, vec3(1.0, 0.12, 0.08), 0.7);
#elif defined(LAYER_COUNT)
    uint k = texelFetch(uQ, t, 0).r;
    c = colormap(float(k) / max(uMax, 1.0));
    if ((flags & FLAG_FEWER) != 0u) c = vec3(1.0, 0.0, 1.0);
#elif defined(LAYER_STATUS)
    uint code = (texelFetch(uS, t, 0).r >> uint(uShift)) & 3u;
    c = code == 0u ? vec3(0.24, 0.56, 0.30) : code == 1u ? vec3(0.14, 0.26, 0.68)
      : code == 2u ? vec3(1.0, 0.84, 0.0) : vec3(0.86, 0.16, 0.16);
#elif defined(LAYER_GLOSS)
    vec2 g = texelFetch(uG, t, 0).rg;
    float x = uGloss == 0 ? g.r : g.g;
    c = x >= 0.0 ? colormap(x / uMax) : vec3(0.3);
#elif defined(LAYER_ERROR)
    float e = texelFetch(uR, t, 0).g;
    c = e >= 0.0 ? colormap(e / uMax) : vec3(0.3);
#endif
  }
  outColor = vec4(c, 1.0);
}
