#version 300 es
// Ray marching through the volume, in texture space t in [0, 1]^3 (x, y, z of the grid).
// Mode 0: the first crossing of uField >= uThreshold, refined by bisection and lit from the
// gradient of uSmooth (Blinn-Phong, two lights); where the clipping box cuts the solid, the
// cut face shows the colour inside. Mode 1: emission-absorption fog of uField.
precision highp float;
precision highp sampler3D;

in vec2 vNdc;
out vec4 outColor;

uniform sampler3D uField;   // R8, linear: coverage, visible labels, distance or density
uniform sampler3D uSmooth;  // R8, linear: uField smoothed, for the normals
uniform sampler3D uColor;   // RGBA8, nearest: the voxels' colours
uniform sampler3D uCoarse;  // R8, nearest: max of uField over each BLOCK³ block and a voxel around
uniform mat4 uInvViewProj;
uniform vec3 uEye;          // camera position, normalised world (the box is uExt wide)
uniform vec3 uExt;          // the shown grid's extent, its longest side 1
uniform vec3 uShape;        // voxels of the shown grid
uniform vec3 uClipLo;
uniform vec3 uClipHi;
uniform float uThreshold;
uniform int uMode;
uniform bool uHasColor;
uniform vec3 uBaseColor;
uniform float uOpacity;
uniform vec3 uBg;
uniform bool uShowBox;
uniform float uPixel;       // a pixel's width at distance 1
uniform vec3 uLight1;       // towards the key light, world
uniform vec3 uLight2;       // towards the fill light, world
uniform bool uShowSlices;   // tint the three slices' planes
uniform vec3 uSlice;        // their positions (voxel centres)
uniform float uSkipBelow;   // a block whose max is below this holds nothing to draw

const float BLOCK = 8.0;

// Where the ray leaves the block holding o + d * t (empty-space skipping), at least t.
float blockExit(vec3 o, vec3 d, vec3 invd, float t) {
  vec3 bi = floor((o + d * t) * uShape / BLOCK);
  vec3 far = (bi + step(0.0, d)) * BLOCK / uShape;
  vec3 tb = (far - o) * invd;
  return max(min(min(tb.x, tb.y), tb.z), t);
}

bool emptyBlock(vec3 p) {
  ivec3 last = textureSize(uCoarse, 0) - 1;
  ivec3 bi = clamp(ivec3(floor(p * uShape / BLOCK)), ivec3(0), last);
  return texelFetch(uCoarse, bi, 0).r < uSkipBelow;
}

vec2 boxHit(vec3 o, vec3 invd, vec3 lo, vec3 hi, out int axis) {
  vec3 t0 = (lo - o) * invd;
  vec3 t1 = (hi - o) * invd;
  vec3 tmin = min(t0, t1);
  vec3 tmax = max(t0, t1);
  float tn = max(max(tmin.x, tmin.y), tmin.z);
  float tf = min(min(tmax.x, tmax.y), tmax.z);
  axis = tn == tmin.x ? 0 : (tn == tmin.y ? 1 : 2);
  return vec2(tn, tf);
}

float field(vec3 p) { return texture(uField, p).r; }

vec3 normalAt(vec3 p, vec3 dirT) {
  vec3 h = 1.0 / uShape;
  vec3 g = vec3(
    texture(uSmooth, p + vec3(h.x, 0.0, 0.0)).r - texture(uSmooth, p - vec3(h.x, 0.0, 0.0)).r,
    texture(uSmooth, p + vec3(0.0, h.y, 0.0)).r - texture(uSmooth, p - vec3(0.0, h.y, 0.0)).r,
    texture(uSmooth, p + vec3(0.0, 0.0, h.z)).r - texture(uSmooth, p - vec3(0.0, 0.0, h.z)).r);
  g = g / (2.0 * h);            // d field / d t
  vec3 n = -g / uExt;           // outward, in world: d t / d world = 1 / uExt
  float len = length(n);
  return len > 1e-6 ? n / len : -normalize(dirT * uExt);
}

vec4 colourAt(vec3 p, vec3 stepT, vec3 inward) {
  // Nearest voxel: step into the solid until a voxel with colour is found.
  for (int k = 1; k <= 6; k++) {
    vec4 c = texture(uColor, p + stepT * float(k) * 0.6 + inward * float(k) * 0.3);
    if (c.a > 0.0) return c;
  }
  return texture(uColor, p);
}

vec3 shade(vec3 base, vec3 n, vec3 view) {
  n = dot(n, view) > 0.0 ? n : -n;  // faces seen from behind (inside a cut) are lit too
  float d1 = max(dot(n, uLight1), 0.0);
  float d2 = max(dot(n, uLight2), 0.0);
  vec3 h = normalize(uLight1 + view);
  float spec = pow(max(dot(n, h), 0.0), 48.0);
  return base * (0.22 + 0.70 * d1 + 0.25 * d2) + vec3(0.22 * spec);
}

bool nearEdge(vec3 p, float width) {
  vec3 dl = abs(p - uClipLo) * uExt;
  vec3 dh = abs(p - uClipHi) * uExt;
  vec3 e = min(dl, dh);
  int count = int(e.x < width) + int(e.y < width) + int(e.z < width);
  return count >= 2;
}

// Where the three slices are: a faint tint where the ray crosses one in front of the surface
// (the slices themselves are drawn beside the view).
vec3 slices(vec3 o, vec3 invd, float tn, float tEnd, vec3 col) {
  for (int a = 0; a < 3; a++) {
    float tp = (uSlice[a] - o[a]) * invd[a];
    vec3 p = o + tp / invd;
    if (tp > tn && tp < tEnd && all(greaterThanEqual(p, uClipLo - 1e-6)) && all(lessThanEqual(p, uClipHi + 1e-6))) {
      col = mix(col, vec3(0.4, 0.6, 0.9), 0.16);
    }
  }
  return col;
}

void main() {
  vec4 a = uInvViewProj * vec4(vNdc, -1.0, 1.0);
  vec4 b = uInvViewProj * vec4(vNdc, 1.0, 1.0);
  vec3 dir = normalize(b.xyz / b.w - a.xyz / a.w);
  vec3 o = uEye / uExt + 0.5;
  vec3 d = dir / uExt;            // per unit of world distance
  d = mix(d, vec3(1e-7), lessThan(abs(d), vec3(1e-7)));
  vec3 invd = 1.0 / d;
  int axis;
  vec2 t = boxHit(o, invd, uClipLo, uClipHi, axis);
  vec3 col = uBg;
  if (t.x >= t.y || t.y <= 0.0) { outColor = vec4(col, 1.0); return; }
  float tn = max(t.x, 0.0);
  float stepLen = 0.5 / max(max(abs(d.x) * uShape.x, abs(d.y) * uShape.y), abs(d.z) * uShape.z);
  vec3 stepT = d * stepLen;
  vec3 view = -dir;
  bool hit = false;
  float tHit = t.y;
  if (uMode == 0) {
    vec3 p = o + d * tn;
    if (field(p) >= uThreshold) {
      // The ray enters the clipping box inside the solid: a cut face.
      vec3 n = vec3(0.0);
      n[axis] = -sign(d[axis]);
      vec4 c = uHasColor ? colourAt(p, stepT, -n / uShape) : vec4(uBaseColor, 1.0);
      // Flatter light than on the surface: a cut face is read for its colours.
      float lit = max(dot(normalize(n / uExt), uLight1), 0.0);
      col = (c.a > 0.0 ? c.rgb : uBaseColor) * (0.62 + 0.38 * lit);
      hit = true;
      tHit = tn;
    } else {
      float tt = tn;  // below the threshold here, and at every tt after
      for (int i = 0; i < 4096; i++) {
        float next = tt + stepLen;
        if (next > t.y) break;
        if (emptyBlock(o + d * next)) {
          tt = blockExit(o, d, invd, next);
          continue;
        }
        if (field(o + d * next) >= uThreshold) {
          float lo = tt, hi = next;
          for (int k = 0; k < 7; k++) {
            float m = 0.5 * (lo + hi);
            if (field(o + d * m) >= uThreshold) hi = m; else lo = m;
          }
          p = o + d * hi;
          vec3 n = normalAt(p, d);
          vec3 nT = normalize(n * uExt);
          vec4 c = uHasColor ? colourAt(p, stepT, -nT / uShape) : vec4(uBaseColor, 1.0);
          col = shade(c.a > 0.0 ? c.rgb : uBaseColor, n, view);
          hit = true;
          tHit = hi;
          break;
        }
        tt = next;
      }
    }
  } else {
    vec3 acc = vec3(0.0);
    float alpha = 0.0;
    float tt = tn + 0.5 * stepLen;
    for (int i = 0; i < 4096; i++) {
      if (tt > t.y || alpha > 0.985) break;
      vec3 p = o + d * tt;
      if (emptyBlock(p)) {
        tt = blockExit(o, d, invd, tt) + 0.01 * stepLen;
        continue;
      }
      float v = field(p);
      if (v > 0.002) {
        float s = 1.0 - exp(-v * uOpacity * 40.0 * stepLen);
        vec3 c = uHasColor ? texture(uColor, p).rgb
                           : mix(vec3(0.25, 0.45, 0.95), vec3(1.0, 0.93, 0.75), v);
        acc += (1.0 - alpha) * s * c;
        alpha += (1.0 - alpha) * s;
      }
      tt += stepLen;
    }
    col = acc + (1.0 - alpha) * uBg;
    hit = alpha > 0.5;
  }
  if (uShowSlices && uMode == 0) col = slices(o, invd, tn, tHit, col);
  if (uShowBox) {
    if (t.x > 0.0 && nearEdge(o + d * t.x, uPixel * t.x * 1.6)) col = mix(col, vec3(1.0, 0.75, 0.25), 0.9);
    else if (!hit && nearEdge(o + d * t.y, uPixel * t.y * 1.2)) col = mix(col, vec3(1.0, 0.75, 0.25), 0.45);
  }
  outColor = vec4(col, 1.0);
}
