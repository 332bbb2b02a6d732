#version 300 es
// One tile: a unit quad placed at uRect (level-0 image pixels: x0, y0, width, height) and mapped
// to clip space by uView (clip = image * uView.xy + uView.zw; image y grows downward).
in vec2 aPos;
uniform vec4 uRect;
uniform vec4 uView;
out vec2 vUV;
void main() {
  vec2 p = uRect.xy + aPos * uRect.zw;
  vUV = aPos;
  gl_Position = vec4(p * uView.xy + uView.zw, 0.0, 1.0);
}
