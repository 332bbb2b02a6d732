#version 300 es
// The 3D view: mesh vertices in the image frame (x = col, y = -row, z = depth).
in vec3 aPos;
in vec3 aNormal;
in vec3 aAlbedo;          // albedo / white
uniform mat4 uMVP;
out vec3 vPos;
out vec3 vNormal;
out vec3 vAlbedo;
void main() {
  vPos = aPos;
  vNormal = aNormal;
  vAlbedo = aAlbedo;
  gl_Position = uMVP * vec4(aPos, 1.0);
}
