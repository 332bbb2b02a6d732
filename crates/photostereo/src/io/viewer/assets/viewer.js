// photostereo result viewer. No external code, no network: the maps come from view/*.js files
// (PSV.tile / PSV.mesh calls carrying base64 zlib payloads), see viewer/tiles.rs.
'use strict';
(function () {
  const M = JSON.parse(document.getElementById('ps-manifest').textContent);
  const SH = JSON.parse(document.getElementById('ps-shaders').textContent);
  const T0 = performance.now();
  const $ = (id) => document.getElementById(id);
  const TILE = M.tile;
  const LEVELS = M.levels;
  const TOP = LEVELS.length - 1;
  const NL = M.lights ? M.lights.count : 0;
  const DIRS = M.lights && M.lights.directions ? M.lights.directions : null;
  const LAYER_INFO = {
    relight: { label: 'relight', groups: ['n', 'a'] },
    normals: { label: 'normals', groups: ['n'] },
    albedo: { label: 'albedo', groups: ['n', 'a'] },
    depth: { label: 'depth', groups: ['q', 'd'] },
    unreliable: { label: 'unreliable', groups: ['q', 'r'] },
    count: { label: 'unusable lights', groups: ['q'] },
    status: { label: 'light status', groups: ['q', 's'] },
    error: { label: 'error', groups: ['q', 'r'] },
    rti: { label: 'RTI', groups: ['n', 'a', 'c', 'u'] },
    gloss: { label: 'gloss', groups: ['q', 'g'] },
    mesh: { label: '3D', groups: [] },
  };
  const STATUS_NAMES = ['used', 'shadow', 'highlight', 'rejected'];
  const STATUS_COLORS = ['#3d8f4d', '#2442ad', '#ffd600', '#db2929'];
  const CMAP = [[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
    [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]];

  // ---------------------------------------------------------------- state and URL fragment
  const S = {
    layer: 'relight',
    light: M.defaults.light.slice(),
    exposure: 0,
    specular: 0,
    shininess: M.defaults.shininess,
    ambient: 0,
    srgb: true,
    dgain: 1,
    unsharp: 0,
    gloss: 'strength',
    k: 1,
    probe: null,
    plain: false,
    fit: 'all',
    zoom: null,
    center: null,
    bench: 0,
    orbit: null,
  };
  const view = { zoom: 1, cx: M.width / 2, cy: M.height / 2 };
  const status = { ready: false, error: null, firstDrawMs: null, readyMs: null, level: 0, drawn: 0 };

  function norm3(v) {
    const l = Math.hypot(v[0], v[1], v[2]);
    return l > 0 ? [v[0] / l, v[1] / l, v[2] / l] : [0, 0, 1];
  }
  function nums(s, n) {
    const v = String(s).split(',').map(Number);
    return v.length === n && v.every(Number.isFinite) ? v : null;
  }
  function parseHash() {
    const h = decodeURIComponent(location.hash.replace(/^#/, ''));
    for (const part of h.split('&')) {
      const i = part.indexOf('=');
      const key = i < 0 ? part : part.slice(0, i);
      const val = i < 0 ? '1' : part.slice(i + 1);
      let v;
      switch (key) {
        case 'layer': if (LAYER_INFO[val] && M.layers.includes(val)) S.layer = val; break;
        case 'light': if ((v = nums(val, 3))) S.light = norm3(v); break;
        case 'exposure': case 'specular': case 'shininess': case 'ambient':
          if (Number.isFinite(+val)) S[key] = +val; break;
        case 'srgb': S.srgb = val !== '0'; break;
        case 'dgain': case 'unsharp': if (Number.isFinite(+val)) S[key] = +val; break;
        case 'gloss': S.gloss = val === 'roughness' ? 'roughness' : 'strength'; break;
        case 'k': if (Number.isInteger(+val)) S.k = Math.min(Math.max(+val, 1), Math.max(NL, 1)); break;
        case 'probe': if ((v = nums(val, 2))) S.probe = v.map(Math.round); break;
        case 'plain': S.plain = val !== '0'; break;
        case 'fit': S.fit = val === '1:1' ? '1:1' : 'all'; break;
        case 'zoom': if (+val > 0) S.zoom = +val; break;
        case 'center': if ((v = nums(val, 2))) S.center = v; break;
        case 'orbit': if ((v = nums(val, 2))) S.orbit = v; break;
        case 'bench': S.bench = Math.max(0, Math.round(+val) || 0); break;
      }
    }
    S.specular = Math.min(Math.max(S.specular, 0), 10);
    S.shininess = Math.min(Math.max(S.shininess, 1), 10000);
    S.ambient = Math.min(Math.max(S.ambient, 0), 1);
    S.dgain = Math.min(Math.max(S.dgain, 0), 20);
    S.unsharp = Math.min(Math.max(S.unsharp, 0), 20);
  }
  const r4 = (x) => +x.toFixed(4);
  let hashTimer = 0;
  function writeHash() {
    clearTimeout(hashTimer);
    hashTimer = setTimeout(() => {
      const p = ['layer=' + S.layer, 'light=' + S.light.map(r4).join(',')];
      if (S.exposure) p.push('exposure=' + r4(S.exposure));
      if (S.specular) p.push('specular=' + r4(S.specular));
      if (S.shininess !== M.defaults.shininess) p.push('shininess=' + r4(S.shininess));
      if (S.ambient) p.push('ambient=' + r4(S.ambient));
      if (!S.srgb) p.push('srgb=0');
      if (S.dgain !== 1) p.push('dgain=' + r4(S.dgain));
      if (S.unsharp) p.push('unsharp=' + r4(S.unsharp));
      if (S.layer === 'gloss') p.push('gloss=' + S.gloss);
      if (S.layer === 'status') p.push('k=' + S.k);
      if (S.probe) p.push('probe=' + S.probe.join(','));
      if (S.plain) p.push('plain=1');
      if (S.fit === '1:1') p.push('fit=1:1');
      if (S.layer === 'mesh') p.push('orbit=' + (mesh.yaw * 180 / Math.PI).toFixed(1) + ',' + (mesh.pitch * 180 / Math.PI).toFixed(1));
      if (S.layer !== 'mesh' && userMovedView) {
        p.push('zoom=' + r4(view.zoom), 'center=' + view.cx.toFixed(1) + ',' + view.cy.toFixed(1));
      }
      const h = '#' + p.join('&');
      if (h !== location.hash) history.replaceState(null, '', h);
    }, 150);
  }
  let userMovedView = false;
  parseHash();
  if (S.plain) { document.body.classList.add('plain'); S.fit = '1:1'; }

  // ---------------------------------------------------------------- WebGL
  const canvas = $('gl');
  const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true, alpha: false });
  function fail(msg) {
    status.error = msg;
    const m = $('message');
    m.textContent = msg;
    m.hidden = false;
    publish();
  }
  if (!gl) { fail('This page needs WebGL2, which this browser does not offer.'); return; }
  if (typeof DecompressionStream === 'undefined') {
    fail('This page needs DecompressionStream (Chromium 80+, Firefox 113+, Safari 16.4+).');
    return;
  }
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);

  function compile(type, src) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  }
  function link(vs, fs) {
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl.VERTEX_SHADER, vs));
    gl.attachShader(p, compile(gl.FRAGMENT_SHADER, fs));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    const u = {};
    const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < n; i++) {
      const name = gl.getActiveUniform(p, i).name;
      u[name] = gl.getUniformLocation(p, name);
    }
    return { p, u };
  }
  const programs = {};
  function imageProgram(layer) {
    if (!programs[layer]) {
      const src = SH.imageFrag.replace('#version 300 es', '#version 300 es\n#define LAYER_' + layer.toUpperCase());
      programs[layer] = link(SH.imageVert, src);
    }
    return programs[layer];
  }
  const quad = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, quad);
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([0, 0, 1, 0, 0, 1, 1, 1]), gl.STATIC_DRAW);
  const quadVao = gl.createVertexArray();
  gl.bindVertexArray(quadVao);
  gl.enableVertexAttribArray(0);
  gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
  gl.bindVertexArray(null);

  // Texture formats per group: [internal format, format, type, bytes per texel, typed array].
  const FORMATS = {
    n: [gl.RGB16UI, gl.RGB_INTEGER, gl.UNSIGNED_SHORT, 6, Uint16Array],
    a: [gl.RGB16UI, gl.RGB_INTEGER, gl.UNSIGNED_SHORT, 6, Uint16Array],
    d: [gl.RGB8, gl.RGB, gl.UNSIGNED_BYTE, 3, Uint8Array],
    q: [gl.RG8UI, gl.RG_INTEGER, gl.UNSIGNED_BYTE, 2, Uint8Array],
    r: [gl.RG32F, gl.RG, gl.FLOAT, 8, Float32Array],
    s: [gl.R8UI, gl.RED_INTEGER, gl.UNSIGNED_BYTE, 1, Uint8Array],
    c: [gl.RGBA16UI, gl.RGBA_INTEGER, gl.UNSIGNED_SHORT, 8, Uint16Array],
    u: [gl.RGB16UI, gl.RGB_INTEGER, gl.UNSIGNED_SHORT, 6, Uint16Array],
    g: [gl.RG32F, gl.RG, gl.FLOAT, 8, Float32Array],
  };
  const UNITS = { n: 0, a: 1, d: 2, q: 3, r: 4, s: 5, c: 6, u: 7, g: 8 };
  const SAMPLERS = { n: 'uN', a: 'uA', d: 'uD', q: 'uQ', r: 'uR', s: 'uS', c: 'uC', u: 'uU', g: 'uG' };
  // The RTI planes' texture holds its layers of four planes one under the other.
  const RTI_LAYERS = M.rti ? Math.ceil(M.rti.planes / 4) : 1;

  // ---------------------------------------------------------------- loading tiles
  window.PSV = window.PSV || {};
  const waiters = new Map();
  PSV.tile = function (key, b64) {
    const w = waiters.get(key);
    if (w) { waiters.delete(key); w.resolve(b64); }
  };
  PSV.mesh = PSV.tile;
  function loadScript(src, key) {
    return new Promise((resolve, reject) => {
      waiters.set(key, { resolve, reject });
      const s = document.createElement('script');
      s.src = src;
      s.onload = () => {
        s.remove();
        if (waiters.has(key)) { waiters.delete(key); reject(new Error('no data in ' + src)); }
      };
      s.onerror = () => { s.remove(); waiters.delete(key); reject(new Error('cannot load ' + src)); };
      document.head.appendChild(s);
    });
  }
  async function inflate(b64) {
    const bin = atob(b64);
    const u8 = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) u8[i] = bin.charCodeAt(i);
    const stream = new Blob([u8]).stream().pipeThrough(new DecompressionStream('deflate'));
    return await new Response(stream).arrayBuffer();
  }
  function tileDims(l, r, c) {
    const L = LEVELS[l];
    return [Math.min(TILE, L.width - c * TILE), Math.min(TILE, L.height - r * TILE)];
  }
  const cache = new Map(); // key "l/r_c/g" -> entry
  const queue = [];
  let inFlight = 0;
  const MAX_IN_FLIGHT = 4;
  const MAX_TILES = 240;
  let useClock = 0;
  function entry(l, r, c, g) { return cache.get(l + '/' + r + '_' + c + '/' + g); }
  function want(l, r, c, g, front) {
    const key = l + '/' + r + '_' + c + '/' + g;
    if (cache.has(key) || !M.groups.includes(g)) return;
    cache.set(key, { state: 'queued', l, r, c, g, used: ++useClock });
    if (front) queue.unshift(key); else queue.push(key);
  }
  function pump() {
    while (inFlight < MAX_IN_FLIGHT && queue.length) {
      const key = queue.shift();
      const e = cache.get(key);
      if (!e || e.state !== 'queued') continue;
      e.state = 'loading';
      inFlight++;
      const src = 'view/tiles/' + e.l + '/' + e.r + '_' + e.c + '.' + e.g + '.js';
      loadScript(src, key).then(inflate).then((buf) => {
        const [w, h] = tileDims(e.l, e.r, e.c);
        const F = FORMATS[e.g];
        e.data = new F[4](buf);
        e.w = w; e.h = h;
        e.tex = gl.createTexture();
        gl.bindTexture(gl.TEXTURE_2D, e.tex);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
        if (e.g === 's') { e.plane = -1; gl.texStorage2D(gl.TEXTURE_2D, 1, F[0], w, h); }
        else gl.texImage2D(gl.TEXTURE_2D, 0, F[0], w, e.g === 'c' ? h * RTI_LAYERS : h, 0, F[1], F[2], e.data);
        // Keep the CPU copy only where the page reads it again (statuses, level 0 for the probe).
        if (e.g !== 's' && e.l !== 0) e.data = null;
        e.state = 'ready';
      }).catch((err) => {
        e.state = 'failed';
        status.error = String(err.message || err);
      }).finally(() => {
        inFlight--;
        evict();
        requestDraw();
        pump();
      });
    }
  }
  function evict() {
    if (cache.size <= MAX_TILES) return;
    const old = [...cache.entries()].filter(([, e]) => e.state === 'ready' && e.l !== TOP)
      .sort((a, b) => a[1].used - b[1].used);
    for (const [key, e] of old.slice(0, cache.size - MAX_TILES)) {
      if (e.used >= useClock - 64) break;
      gl.deleteTexture(e.tex);
      cache.delete(key);
    }
  }
  function ready(l, r, c, g) {
    const e = entry(l, r, c, g);
    return e && e.state === 'ready';
  }

  // ---------------------------------------------------------------- view transform
  function resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(canvas.clientWidth * dpr));
    const h = Math.max(1, Math.round(canvas.clientHeight * dpr));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  }
  function fitView(mode) {
    const cw = canvas.clientWidth, ch = canvas.clientHeight;
    if (mode === '1:1') {
      view.zoom = 1;
      view.cx = cw / 2;
      view.cy = ch / 2;
    } else {
      view.zoom = Math.min(cw / M.width, ch / M.height) * 0.96;
      view.cx = M.width / 2;
      view.cy = M.height / 2;
    }
  }
  function screenToImage(x, y) {
    return [view.cx + (x - canvas.clientWidth / 2) / view.zoom, view.cy + (y - canvas.clientHeight / 2) / view.zoom];
  }
  function imageToScreen(ix, iy) {
    return [(ix - view.cx) * view.zoom + canvas.clientWidth / 2, (iy - view.cy) * view.zoom + canvas.clientHeight / 2];
  }
  function targetLevel() {
    const z = view.zoom * (window.devicePixelRatio || 1);
    if (z >= 1) return 0;
    return Math.min(TOP, Math.max(0, Math.floor(Math.log2(1 / z) + 1e-9)));
  }
  function visibleTiles(l) {
    const s = 2 ** l;
    const [x0, y0] = screenToImage(0, 0);
    const [x1, y1] = screenToImage(canvas.clientWidth, canvas.clientHeight);
    const L = LEVELS[l];
    const c0 = Math.max(0, Math.floor(x0 / s / TILE)), c1 = Math.min(L.cols - 1, Math.floor(x1 / s / TILE));
    const r0 = Math.max(0, Math.floor(y0 / s / TILE)), r1 = Math.min(L.rows - 1, Math.floor(y1 / s / TILE));
    const out = [];
    for (let r = r0; r <= r1; r++) for (let c = c0; c <= c1; c++) out.push([r, c]);
    const [mx, my] = [(x0 + x1) / 2 / s / TILE, (y0 + y1) / 2 / s / TILE];
    out.sort((a, b) => Math.hypot(a[1] + 0.5 - mx, a[0] + 0.5 - my) - Math.hypot(b[1] + 0.5 - mx, b[0] + 0.5 - my));
    return out;
  }

  // ---------------------------------------------------------------- drawing
  let drawPending = false;
  function requestDraw() {
    if (drawPending) return;
    drawPending = true;
    requestAnimationFrame(() => { drawPending = false; draw(); });
  }
  function lightUniforms(u) {
    gl.uniform3fv(u.uLight, norm3(S.light));
    gl.uniform1f(u.uGain, Math.pow(2, S.exposure));
    gl.uniform1f(u.uSpec, S.specular);
    gl.uniform1f(u.uShine, S.shininess);
    gl.uniform1f(u.uAmbient, S.ambient);
    gl.uniform1i(u.uSrgb, S.srgb ? 1 : 0);
  }
  // ---------------------------------------------------------------- RTI (viewer/rti.rs)
  // The basis functions of PTM and HSH at the unit light l (solve/rti/mod.rs, Basis::eval).
  function basisEval(name, l) {
    if (name === 'ptm' || name === 'ptm-rgb') return [l[0] * l[0], l[1] * l[1], l[0] * l[1], l[0], l[1], 1];
    const ct = Math.min(Math.max(l[2], 0), 1), phi = Math.atan2(l[1], l[0]);
    const s = Math.sqrt(Math.max(ct - ct * ct, 0)), PI = Math.PI, k = Math.sqrt(30 / PI);
    const b = [1 / Math.sqrt(2 * PI), Math.sqrt(6 / PI) * Math.cos(phi) * s,
      Math.sqrt(3 / (2 * PI)) * (2 * ct - 1), Math.sqrt(6 / PI) * Math.sin(phi) * s];
    if (name === 'hsh3') {
      b.push(k * Math.cos(2 * phi) * (ct * ct - ct), k * Math.cos(phi) * (2 * ct - 1) * s,
        Math.sqrt(5 / (2 * PI)) * (6 * ct * ct - 6 * ct + 1), k * Math.sin(phi) * (2 * ct - 1) * s,
        k * Math.sin(2 * phi) * (ct * ct - ct));
    }
    return b;
  }
  // relight's RBF: normalised Gaussian weights of l over the lights, those not above
  // min_weight dropped and the rest renormalised; the nearest light alone when all underflow.
  function rbfWeights(R, l) {
    const L = R.lights, r = 1 / (R.sigma * R.sigma);
    const d2 = L.map((li) => (li[0] - l[0]) ** 2 + (li[1] - l[1]) ** 2 + (li[2] - l[2]) ** 2);
    let w = d2.map((d) => Math.exp(-r * d));
    const total = w.reduce((a, b) => a + b, 0);
    if (!(total > 0) || !Number.isFinite(total)) {
      let best = 0;
      d2.forEach((d, i) => { if (d < d2[best]) best = i; });
      return w.map((_, i) => (i === best ? 1 : 0));
    }
    w = w.map((x) => { const y = x / total; return y > R.min_weight ? y : 0; });
    const kept = w.reduce((a, b) => a + b, 0);
    return w.map((x) => x / kept);
  }
  // The planes' weights under l: w0 (3) and w (K × 3).
  function rtiWeights(l) {
    const R = M.rti, K = R.coefficient_planes, w = new Float32Array(27 * 3), w0 = [0, 0, 0];
    if (R.rbf) {
      const m = R.rbf, c = m.channels, n = m.lights.length, d = n * c, wt = rbfWeights(m, l);
      for (let i = 0; i < n; i++) {
        if (!(wt[i] > 0)) continue;
        for (let ch = 0; ch < 3; ch++) {
          const cc = Math.min(ch, c - 1);
          w0[ch] += wt[i] * m.mean[i * c + cc];
          for (let j = 0; j < K; j++) w[j * 3 + ch] += wt[i] * m.planes[j * d + i * c + cc];
        }
      }
      return { w0, w };
    }
    const b = basisEval(R.basis, l), T = R.terms;
    for (let q = 0; q < K; q++) {
      const ch = Math.floor(q / T), j = q % T;
      for (let c = 0; c < 3; c++) w[q * 3 + c] = R.fitted_channels === 1 || c === ch ? b[j] : 0;
    }
    return { w0, w };
  }
  function rtiUniforms(u) {
    const R = M.rti, l = norm3(S.light), { w0, w } = rtiWeights(l);
    gl.uniform1i(u.uPlanes, R.coefficient_planes);
    gl.uniform1i(u.uChroma, R.chroma ? 1 : 0);
    const lo = new Float32Array(32), span = new Float32Array(32);
    lo.set(R.lo); span.set(R.span);
    gl.uniform1fv(u['uLo[0]'], lo);
    gl.uniform1fv(u['uSpan[0]'], span);
    gl.uniform3fv(u['uW[0]'], w);
    gl.uniform3fv(u.uW0, w0);
    const ptm = R.basis === 'ptm' || R.basis === 'ptm-rgb';
    gl.uniform1i(u.uPtm, ptm ? 1 : 0);
    gl.uniform1i(u.uFc, R.fitted_channels);
    gl.uniform1fv(u['uB[0]'], new Float32Array(basisEval('ptm', l)));
    gl.uniform1f(u.uDGain, ptm ? S.dgain : 1);
    gl.uniform1f(u.uSharp, S.unsharp);
  }
  function layerMax() {
    switch (S.layer) {
      case 'unreliable': return M.residual ? M.residual.max : 1;
      case 'count': return Math.max(NL, 1);
      case 'error': return M.error ? M.error.max_deg : 45;
      case 'gloss': return M.gloss ? (S.gloss === 'roughness' ? M.gloss.roughness_max : M.gloss.strength_max) : 1;
      default: return 1;
    }
  }
  function draw() {
    resize();
    // Until the user pans or zooms, the view follows the window (headless screenshots resize it).
    if (!userMovedView) fitView(S.fit);
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(0, 0, 0, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (S.layer === 'mesh') { drawMesh(); afterDraw(mesh.state === 'ready' || mesh.state === 'failed'); return; }
    gl.disable(gl.DEPTH_TEST);
    const prog = imageProgram(S.layer);
    const u = prog.u;
    gl.useProgram(prog.p);
    gl.bindVertexArray(quadVao);
    const dpr = window.devicePixelRatio || 1;
    const z = view.zoom * dpr, W = canvas.width, H = canvas.height;
    // clip = (image - center) * z * 2 / size, y down in the image, up in clip space.
    gl.uniform4f(u.uView, 2 * z / W, -2 * z / H, -2 * z * view.cx / W, 2 * z * view.cy / H);
    lightUniforms(u);
    gl.uniform1f(u.uWhite, M.albedo.white);
    gl.uniform1f(u.uAlbedoMax, M.albedo.max);
    gl.uniform1f(u.uMax, layerMax());
    gl.uniform3f(u.uBg, 0, 0, 0);
    if (S.layer === 'rti') rtiUniforms(u);
    if (S.layer === 'gloss') gl.uniform1i(u.uGloss, S.gloss === 'roughness' ? 1 : 0);
    const plane = (S.k - 1) >> 2;
    gl.uniform1i(u.uShift, 2 * ((S.k - 1) & 3));
    const groups = LAYER_INFO[S.layer].groups;
    for (const g of groups) if (u[SAMPLERS[g]]) gl.uniform1i(u[SAMPLERS[g]], UNITS[g]);
    const target = targetLevel();
    status.level = target;
    let complete = true;
    let drawn = 0;
    // Coarse to fine: the top level (always asked for) under whatever finer tiles are ready;
    // once every tile of the target level is ready, that level alone.
    const targetReady = visibleTiles(target).every(([r, c]) => groups.every((g) => ready(target, r, c, g)));
    for (let l = targetReady ? target : TOP; l >= target; l--) {
      const tiles = visibleTiles(l);
      for (const [r, c] of tiles) {
        const ok = groups.every((g) => ready(l, r, c, g));
        if (l === target || l === TOP) {
          for (const g of groups) want(l, r, c, g, l === TOP);
          if (!ok && l === target) {
            if (groups.some((g) => { const e = entry(l, r, c, g); return !e || e.state !== 'failed'; })) complete = false;
          }
        }
        if (!ok) continue;
        const s = 2 ** l;
        const [tw, th] = tileDims(l, r, c);
        for (const g of groups) {
          const e = entry(l, r, c, g);
          e.used = ++useClock;
          gl.activeTexture(gl.TEXTURE0 + UNITS[g]);
          gl.bindTexture(gl.TEXTURE_2D, e.tex);
          if (g === 's' && e.plane !== plane) {
            const n = tw * th;
            gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, tw, th, gl.RED_INTEGER, gl.UNSIGNED_BYTE,
              e.data.subarray(plane * n, (plane + 1) * n));
            e.plane = plane;
          }
        }
        gl.uniform4f(u.uRect, c * TILE * s, r * TILE * s, tw * s, th * s);
        gl.uniform2i(u.uSize, tw, th);
        gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
        drawn++;
      }
    }
    status.drawn = drawn;
    pump();
    afterDraw(complete && inFlight === 0);
  }
  function afterDraw(done) {
    if (status.firstDrawMs === null && status.drawn > 0) status.firstDrawMs = performance.now() - T0;
    if (S.probe) updateProbe();
    done = done && inFlight === 0 && queue.length === 0 && !(probeInfo && probeInfo.pending);
    $('loading').hidden = done;
    if (done && !status.ready) {
      status.ready = true;
      status.readyMs = performance.now() - T0;
      status.readyAt = performance.now();
      if (S.bench) setTimeout(bench, 0);
    } else if (!done) status.ready = false;
    placeMarker();
    publish();
  }

  // ---------------------------------------------------------------- 3D view
  const mesh = { state: 'none', yaw: 0, pitch: 0, dist: 1, pan: [0, 0, 0] };
  if (S.orbit) { mesh.yaw = S.orbit[0] * Math.PI / 180; mesh.pitch = Math.max(-1.5, Math.min(1.5, S.orbit[1] * Math.PI / 180)); }
  function loadMesh() {
    if (mesh.state !== 'none' || !M.mesh) return;
    mesh.state = 'loading';
    const key = M.mesh.vertices + ',' + M.mesh.triangles + ',' + M.mesh.stride;
    loadScript('view/mesh.js', key).then(inflate).then((buf) => {
      const nv = M.mesh.vertices, nt = M.mesh.triangles;
      const f = new Float32Array(buf, 0, nv * 9);
      const idx = new Uint32Array(buf, nv * 36, nt * 3);
      mesh.vao = gl.createVertexArray();
      gl.bindVertexArray(mesh.vao);
      const attr = (loc, off) => {
        const b = gl.createBuffer();
        gl.bindBuffer(gl.ARRAY_BUFFER, b);
        gl.bufferData(gl.ARRAY_BUFFER, f.subarray(off * nv, (off + 3) * nv), gl.STATIC_DRAW);
        gl.enableVertexAttribArray(loc);
        gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
      };
      mesh.prog = link(SH.meshVert, SH.meshFrag);
      attr(gl.getAttribLocation(mesh.prog.p, 'aPos'), 0);
      attr(gl.getAttribLocation(mesh.prog.p, 'aNormal'), 3);
      attr(gl.getAttribLocation(mesh.prog.p, 'aAlbedo'), 6);
      const ib = gl.createBuffer();
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib);
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, idx, gl.STATIC_DRAW);
      gl.bindVertexArray(null);
      let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
      for (let i = 0; i < nv; i++) for (let k = 0; k < 3; k++) {
        const v = f[i * 3 + k];
        if (v < lo[k]) lo[k] = v;
        if (v > hi[k]) hi[k] = v;
      }
      mesh.center = [0, 1, 2].map((k) => (lo[k] + hi[k]) / 2);
      mesh.radius = Math.max(1, Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2);
      mesh.dist = mesh.radius * 4.2;
      mesh.state = 'ready';
    }).catch((err) => { mesh.state = 'failed'; status.error = String(err.message || err); })
      .finally(requestDraw);
  }
  function mat4mul(a, b) {
    const o = new Float32Array(16);
    for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      o[c * 4 + r] = s;
    }
    return o;
  }
  function meshCamera() {
    const cy = Math.cos(mesh.yaw), sy = Math.sin(mesh.yaw), cp = Math.cos(mesh.pitch), sp = Math.sin(mesh.pitch);
    // Camera looks at the centre from +z rotated by yaw (about y) then pitch (about x).
    const fwd = [-sy * cp, sp, -cy * cp]; // from the eye toward the target
    const tgt = mesh.center.map((v, i) => v + mesh.pan[i]);
    const eye = tgt.map((v, i) => v - fwd[i] * mesh.dist);
    const up0 = [0, 1, 0];
    const zx = fwd.map((v) => -v);
    let xx = [up0[1] * zx[2] - up0[2] * zx[1], up0[2] * zx[0] - up0[0] * zx[2], up0[0] * zx[1] - up0[1] * zx[0]];
    xx = norm3(xx);
    const yy = [zx[1] * xx[2] - zx[2] * xx[1], zx[2] * xx[0] - zx[0] * xx[2], zx[0] * xx[1] - zx[1] * xx[0]];
    const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    const V = new Float32Array([xx[0], yy[0], zx[0], 0, xx[1], yy[1], zx[1], 0, xx[2], yy[2], zx[2], 0,
      -dot(xx, eye), -dot(yy, eye), -dot(zx, eye), 1]);
    const aspect = canvas.width / canvas.height, f = 1 / Math.tan(Math.PI / 12);
    const near = mesh.dist / 100, far = mesh.dist + mesh.radius * 4;
    const P = new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) / (near - far), -1,
      0, 0, 2 * far * near / (near - far), 0]);
    return { mvp: mat4mul(P, V), eye, xx, yy };
  }
  function drawMesh() {
    loadMesh();
    if (mesh.state !== 'ready') return;
    gl.enable(gl.DEPTH_TEST);
    const { p, u } = mesh.prog;
    gl.useProgram(p);
    const cam = meshCamera();
    gl.uniformMatrix4fv(u.uMVP, false, cam.mvp);
    gl.uniform3fv(u.uEye, cam.eye);
    lightUniforms(u);
    gl.bindVertexArray(mesh.vao);
    gl.drawElements(gl.TRIANGLES, M.mesh.triangles * 3, gl.UNSIGNED_INT, 0);
    gl.bindVertexArray(null);
    status.drawn = 1;
  }

  // ---------------------------------------------------------------- probe
  let probeInfo = null;
  function probeGroups() { return ['n', 'a', 'q', 'r', 's'].filter((g) => M.groups.includes(g)); }
  function updateProbe() {
    const [row, col] = S.probe;
    if (!(row >= 0 && col >= 0 && row < M.height && col < M.width)) { probeInfo = { row, col, outside_image: true }; renderProbe(); return; }
    const r = Math.floor(row / TILE), c = Math.floor(col / TILE);
    const groups = probeGroups();
    let waiting = false;
    for (const g of groups) {
      const e = entry(0, r, c, g);
      if (!e) { want(0, r, c, g, true); waiting = true; } else if (e.state === 'queued' || e.state === 'loading') waiting = true;
      else if (e.state === 'ready' && !e.data) { cache.delete(0 + '/' + r + '_' + c + '/' + g); gl.deleteTexture(e.tex); want(0, r, c, g, true); waiting = true; }
    }
    if (waiting) { pump(); probeInfo = { row, col, pending: true }; status.ready = false; renderProbe(); return; }
    const [tw] = tileDims(0, r, c);
    const i = (row - r * TILE) * tw + (col - c * TILE);
    const get = (g) => { const e = entry(0, r, c, g); return e && e.state === 'ready' ? e.data : null; };
    const info = { row, col };
    const n = get('n');
    if (n) {
      const code = [n[3 * i], n[3 * i + 1], n[3 * i + 2]];
      info.inside = !(code[0] === 0 && code[1] === 0 && code[2] === 0);
      if (info.inside) {
        info.normal = code.map((v) => v / 65535 * 2 - 1);
        const nn = norm3(info.normal);
        info.slant_deg = Math.acos(Math.min(1, Math.max(-1, nn[2]))) * 180 / Math.PI;
        info.tilt_deg = Math.atan2(nn[1], nn[0]) * 180 / Math.PI;
      }
    }
    const a = get('a');
    if (a && info.inside) info.albedo = [0, 1, 2].slice(0, M.albedo.channels === 1 ? 1 : 3).map((k) => a[3 * i + k] / 65535 * M.albedo.max);
    const q = get('q');
    if (q && info.inside) {
      info.unusable = q[2 * i];
      const f = q[2 * i + 1];
      info.unreliable = !!(f & 2);
      info.highlight = !!(f & 4);
      info.fewer_than_three = !!(f & 8);
    }
    const rr = get('r');
    if (rr && info.inside) {
      info.residual = rr[2 * i] >= 0 ? rr[2 * i] : null;
      info.error_deg = rr[2 * i + 1] >= 0 ? rr[2 * i + 1] : null;
    }
    const s = get('s');
    if (s && info.inside) {
      const [tw2, th2] = tileDims(0, r, c);
      const np = tw2 * th2;
      const lists = { used: [], shadow: [], highlight: [], rejected: [] };
      const codes = [];
      for (let k = 0; k < NL; k++) {
        const code = (s[(k >> 2) * np + i] >> (2 * (k & 3))) & 3;
        codes.push(code);
        lists[STATUS_NAMES[code]].push(k + 1);
      }
      info.lights = lists;
      info.codes = codes;
    }
    // The colour drawn at this pixel, when it is on screen (layer checks).
    const [sx, sy] = imageToScreen(col + 0.5, row + 0.5);
    const dpr = window.devicePixelRatio || 1;
    if (S.layer !== 'mesh' && sx >= 0 && sy >= 0 && sx < canvas.clientWidth && sy < canvas.clientHeight) {
      const px = new Uint8Array(4);
      gl.readPixels(Math.floor(sx * dpr), canvas.height - 1 - Math.floor(sy * dpr), 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
      info.rgba = Array.from(px);
    }
    probeInfo = info;
    renderProbe();
  }
  function fmt(v, d) { return v === null || v === undefined ? '—' : (+v).toFixed(d); }
  function renderProbe() {
    const el = $('probe');
    el.textContent = '';
    if (!probeInfo) { el.textContent = '—'; return; }
    const p = probeInfo;
    const rows = [['pixel', 'row ' + p.row + ', col ' + p.col]];
    if (p.outside_image) rows.push(['', 'outside the image']);
    else if (p.pending) rows.push(['', 'loading…']);
    else if (!p.inside) rows.push(['', 'outside the mask']);
    else {
      rows.push(['normal', p.normal.map((v) => fmt(v, 4)).join(', ')]);
      rows.push(['slant/tilt', fmt(p.slant_deg, 1) + '°, ' + fmt(p.tilt_deg, 1) + '°']);
      if (p.albedo) rows.push(['albedo', p.albedo.map((v) => fmt(v, 4)).join(', ')]);
      if (p.residual !== undefined) rows.push(['residual', fmt(p.residual, 3) + (p.unreliable ? '  unreliable' : '')]);
      if (p.error_deg !== undefined && p.error_deg !== null) rows.push(['error', fmt(p.error_deg, 2) + '°']);
      if (p.unusable !== undefined && NL) rows.push(['usable', (NL - p.unusable) + ' of ' + NL + ' lights' + (p.fewer_than_three ? ' (fewer than 3)' : '')]);
      if (p.lights) for (const name of STATUS_NAMES) if (p.lights[name].length && name !== 'used') rows.push([name, compactList(p.lights[name])]);
    }
    const table = document.createElement('table');
    for (const [k, v] of rows) {
      const tr = table.insertRow();
      tr.insertCell().textContent = k;
      tr.insertCell().textContent = v;
    }
    el.appendChild(table);
    if (p.codes) {
      const strip = document.createElement('div');
      strip.className = 'strip';
      p.codes.forEach((code, k) => {
        const sp = document.createElement('span');
        sp.style.background = STATUS_COLORS[code];
        sp.title = 'light ' + (k + 1) + ': ' + STATUS_NAMES[code] + (DIRS ? ' (' + DIRS[k].map((v) => v.toFixed(3)).join(', ') + ')' : '');
        sp.onclick = () => { S.k = k + 1; if (M.layers.includes('status')) setLayer('status'); syncUi(); };
        strip.appendChild(sp);
      });
      el.appendChild(strip);
    }
  }
  function compactList(v) {
    const out = [];
    for (let i = 0; i < v.length;) {
      let j = i;
      while (j + 1 < v.length && v[j + 1] === v[j] + 1) j++;
      out.push(j > i + 1 ? v[i] + '–' + v[j] : j === i + 1 ? v[i] + ',' + v[j] : String(v[i]));
      i = j + 1;
    }
    return out.join(',');
  }
  function placeMarker() {
    const m = $('marker');
    if (!S.probe || S.layer === 'mesh' || S.plain) { m.hidden = true; return; }
    const [x, y] = imageToScreen(S.probe[1] + 0.5, S.probe[0] + 0.5);
    m.style.left = x + 'px';
    m.style.top = y + 'px';
    m.hidden = false;
  }

  // ---------------------------------------------------------------- state for tests and tools
  function publish() {
    const st = {
      ready: status.ready,
      error: status.error,
      layer: S.layer,
      light: S.light,
      exposure: S.exposure,
      specular: S.specular,
      shininess: S.shininess,
      ambient: S.ambient,
      srgb: S.srgb,
      dgain: S.dgain,
      unsharp: S.unsharp,
      gloss: S.gloss,
      k: S.k,
      level: status.level,
      zoom: view.zoom,
      center: [view.cx, view.cy],
      canvas: [canvas.width, canvas.height],
      dpr: window.devicePixelRatio || 1,
      tiles_cached: cache.size,
      first_draw_ms: status.firstDrawMs,
      ready_ms: status.readyMs,
      ready_at_ms: status.readyAt,
      probe: probeInfo,
      mesh: mesh.state,
      bench: benchResult,
      resources: performance.getEntriesByType('resource').map((r) => r.name.split('/').slice(0, 3).join('/'))
        .filter((v, i, a) => a.indexOf(v) === i),
    };
    $('ps-state').textContent = JSON.stringify(st);
  }

  // ---------------------------------------------------------------- benchmark (#bench=N)
  let benchResult = null;
  function bench() {
    const n = S.bench, times = [];
    const px = new Uint8Array(4);
    const saved = S.light.slice();
    for (let i = 0; i < n; i++) {
      const az = 2 * Math.PI * i / n, el = 0.3 + 0.5 * Math.abs(Math.sin(3 * az));
      S.light = [Math.cos(az) * Math.cos(el), Math.sin(az) * Math.cos(el), Math.sin(el)];
      const t = performance.now();
      draw();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px); // wait for the GPU
      times.push(performance.now() - t);
    }
    S.light = saved;
    times.sort((a, b) => a - b);
    benchResult = {
      frames: n,
      mean_ms: times.reduce((a, b) => a + b, 0) / n,
      median_ms: times[Math.floor(n / 2)],
      p95_ms: times[Math.min(n - 1, Math.floor(n * 0.95))],
      max_ms: times[n - 1],
      canvas: [canvas.width, canvas.height],
      level: status.level,
    };
    draw();
  }

  // For tools driving the page (DevTools protocol): timed redraws and view changes.
  PSV.bench = (n) => { S.bench = n; bench(); publish(); return benchResult; };
  PSV.setView = (zoom, cx, cy) => {
    view.zoom = zoom; view.cx = cx; view.cy = cy; userMovedView = true;
    status.ready = false; status.readyMs = null; status.readyAt = null;
    publish();
    requestDraw();
  };
  PSV.state = () => JSON.parse($('ps-state').textContent);

  // ---------------------------------------------------------------- UI
  function setLayer(name) {
    if (!M.layers.includes(name)) return;
    S.layer = name;
    syncUi();
  }
  function syncUi() {
    for (const b of $('layers').children) b.classList.toggle('on', b.dataset.layer === S.layer);
    const lightLayers = ['relight', 'mesh', 'albedo', 'rti'];
    $('rti-section').hidden = !M.rti;
    if (M.rti) {
      const ptm = M.rti.basis === 'ptm' || M.rti.basis === 'ptm-rgb';
      $('dgain').disabled = !ptm;
      $('dgain').value = S.dgain; $('dgain-v').textContent = ptm ? S.dgain.toFixed(1) : 'PTM only';
      $('unsharp').value = S.unsharp; $('unsharp-v').textContent = S.unsharp.toFixed(1);
    }
    $('gloss-section').hidden = !M.gloss;
    if (M.gloss) $('gloss-roughness').checked = S.gloss === 'roughness';
    $('light-section').style.opacity = lightLayers.includes(S.layer) ? 1 : 0.55;
    $('exposure').value = S.exposure; $('exposure-v').textContent = S.exposure.toFixed(1) + ' EV';
    $('specular').value = S.specular; $('specular-v').textContent = S.specular.toFixed(2);
    $('shininess').value = Math.log(S.shininess) / Math.log(1000); $('shininess-v').textContent = S.shininess.toFixed(0);
    $('ambient').value = S.ambient; $('ambient-v').textContent = S.ambient.toFixed(2);
    $('srgb').checked = S.srgb;
    const l = norm3(S.light);
    const el = Math.asin(Math.min(1, Math.max(-1, l[2]))) * 180 / Math.PI;
    const az = Math.atan2(l[1], l[0]) * 180 / Math.PI;
    $('light-readout').textContent = 'l = (' + l.map((v) => v.toFixed(3)).join(', ') + ')\nelevation ' + el.toFixed(1) + '°, azimuth ' + az.toFixed(1) + '°';
    $('status-section').hidden = !NL;
    if (NL) {
      $('k').max = NL; $('k').value = S.k; $('k-v').textContent = S.k + ' / ' + NL;
      $('k-info').textContent = DIRS ? 'direction (' + DIRS[S.k - 1].map((v) => v.toFixed(3)).join(', ') + ')' : 'directions unknown (view --lights FILE)';
      $('preset-capture').hidden = !DIRS;
      $('preset-capture').textContent = 'capture ' + S.k;
    }
    drawLightpad();
    renderLegend();
    if (S.probe) updateProbe(); else renderProbe();
    writeHash();
    requestDraw();
  }
  function buildUi() {
    $('title').textContent = M.title;
    const rep = M.report || {};
    const bits = [M.width + ' × ' + M.height];
    if (rep.method) bits.push(rep.method);
    if (NL) bits.push(NL + ' lights');
    if (M.error && M.error.stats && M.error.stats.mean_deg !== undefined) bits.push('mean error ' + M.error.stats.mean_deg.toFixed(2) + '°');
    $('summary').textContent = bits.join(' · ');
    const box = $('layers');
    let key = 1;
    for (const name of Object.keys(LAYER_INFO)) {
      if (!M.layers.includes(name)) continue;
      const b = document.createElement('button');
      b.textContent = LAYER_INFO[name].label;
      b.dataset.layer = name;
      b.title = 'key ' + key++;
      b.onclick = () => setLayer(name);
      box.appendChild(b);
    }
    const slider = (id, f) => $(id).addEventListener('input', (e) => { f(+e.target.value); syncUi(); });
    slider('exposure', (v) => { S.exposure = v; });
    slider('specular', (v) => { S.specular = v; });
    slider('shininess', (v) => { S.shininess = Math.max(1, Math.round(Math.pow(1000, v))); });
    slider('ambient', (v) => { S.ambient = v; });
    slider('k', (v) => { S.k = v; });
    slider('dgain', (v) => { S.dgain = v; });
    slider('unsharp', (v) => { S.unsharp = v; });
    $('gloss-roughness').addEventListener('change', (e) => { S.gloss = e.target.checked ? 'roughness' : 'strength'; syncUi(); });
    $('srgb').addEventListener('change', (e) => { S.srgb = e.target.checked; syncUi(); });
    $('preset-default').onclick = () => { S.light = M.defaults.light.slice(); syncUi(); };
    $('preset-top').onclick = () => { S.light = [0, 0, 1]; syncUi(); };
    $('preset-raking').onclick = () => {
      const l = norm3(S.light);
      let az = Math.atan2(l[1], l[0]);
      if (Math.hypot(l[0], l[1]) < 1e-3) az = Math.PI * 0.75;
      const el = 10 * Math.PI / 180;
      S.light = [Math.cos(az) * Math.cos(el), Math.sin(az) * Math.cos(el), Math.sin(el)];
      syncUi();
    };
    $('preset-capture').onclick = () => { if (DIRS) { S.light = norm3(DIRS[S.k - 1]); syncUi(); } };
    // The light pad: the upper hemisphere seen from the camera (x right, y up).
    const pad = $('lightpad');
    let padDrag = false;
    const padLight = (e) => {
      const rect = pad.getBoundingClientRect();
      const x = (e.clientX - rect.left) / rect.width * 2 - 1, y = 1 - (e.clientY - rect.top) / rect.height * 2;
      if (DIRS && e.type === 'pointerdown') {
        for (let k = 0; k < NL; k++) {
          const d = norm3(DIRS[k]);
          if (Math.hypot(d[0] - x, d[1] - y) < 0.05) { S.k = k + 1; S.light = d; syncUi(); return; }
        }
      }
      S.light = diskToLight(x, y);
      syncUi();
    };
    pad.addEventListener('pointerdown', (e) => { padDrag = true; pad.setPointerCapture(e.pointerId); padLight(e); });
    pad.addEventListener('pointermove', (e) => { if (padDrag) padLight(e); });
    pad.addEventListener('pointerup', () => { padDrag = false; });
  }
  function diskToLight(x, y) {
    const r = Math.hypot(x, y);
    if (r >= 1) return [x / r, y / r, 0];
    return [x, y, Math.sqrt(1 - r * r)];
  }
  function drawLightpad() {
    const pad = $('lightpad'), c = pad.getContext('2d');
    const w = pad.width, h = pad.height, R = w / 2 - 2;
    c.clearRect(0, 0, w, h);
    c.strokeStyle = '#444';
    for (const el of [0, 30, 60]) {
      c.beginPath(); c.arc(w / 2, h / 2, R * Math.cos(el * Math.PI / 180), 0, 2 * Math.PI); c.stroke();
    }
    c.beginPath(); c.moveTo(w / 2 - R, h / 2); c.lineTo(w / 2 + R, h / 2); c.moveTo(w / 2, h / 2 - R); c.lineTo(w / 2, h / 2 + R); c.stroke();
    if (DIRS) {
      DIRS.forEach((d0, k) => {
        const d = norm3(d0);
        c.fillStyle = k + 1 === S.k && NL ? '#ff5a5a' : '#8a8f96';
        c.fillRect(w / 2 + d[0] * R - 1.5, h / 2 - d[1] * R - 1.5, 3, 3);
      });
    }
    const l = norm3(S.light);
    c.fillStyle = '#ffd84a';
    c.beginPath(); c.arc(w / 2 + l[0] * R, h / 2 - l[1] * R, 5, 0, 2 * Math.PI); c.fill();
  }
  function bar(stops, lo, hi, unit) {
    const wrap = document.createElement('div');
    const cv = document.createElement('canvas');
    cv.width = 256; cv.height = 1;
    const c = cv.getContext('2d');
    for (let x = 0; x < 256; x++) { c.fillStyle = stops(x / 255); c.fillRect(x, 0, 1, 1); }
    wrap.appendChild(cv);
    const ticks = document.createElement('div');
    ticks.className = 'ticks';
    for (const v of [lo, (lo + hi) / 2, hi]) {
      const s = document.createElement('span');
      s.textContent = (Math.abs(v) >= 100 ? v.toFixed(0) : Math.abs(v) >= 1 ? v.toFixed(1) : v.toPrecision(2)) + (unit || '');
      ticks.appendChild(s);
    }
    wrap.appendChild(ticks);
    return wrap;
  }
  function cmapCss(t) {
    const x = Math.min(Math.max(t, 0), 1) * 8, i = Math.min(Math.floor(x), 7), f = x - i;
    const c = [0, 1, 2].map((k) => Math.round(CMAP[i][k] * (1 - f) + CMAP[i + 1][k] * f));
    return 'rgb(' + c.join(',') + ')';
  }
  function swatch(color, text) {
    const d = document.createElement('div');
    d.className = 'legend-row';
    const s = document.createElement('span');
    s.className = 'swatch';
    s.style.background = color;
    d.appendChild(s);
    d.appendChild(document.createTextNode(text));
    return d;
  }
  function note(text) { const d = document.createElement('div'); d.className = 'small'; d.textContent = text; return d; }
  function renderLegend() {
    const el = $('legend');
    el.textContent = '';
    const srgb = (v) => { const e = S.srgb ? (v <= 0.0031308 ? 12.92 * v : 1.055 * Math.pow(v, 1 / 2.4) - 0.055) : v; const g = Math.round(255 * Math.min(1, e)); return 'rgb(' + g + ',' + g + ',' + g + ')'; };
    const white = M.albedo.white / Math.pow(2, S.exposure);
    switch (S.layer) {
      case 'relight':
        el.appendChild(note('ρ · (ambient + (1 − ambient) · max(0, n·l)) + specular · (n·h)^shininess, times 2^exposure; albedo ρ shown relative to its 99.5th percentile.'));
        el.appendChild(bar(srgb, 0, white, ''));
        el.appendChild(note('albedo that shows as each grey under a frontal light'));
        break;
      case 'albedo':
        el.appendChild(bar(srgb, 0, white, ''));
        el.appendChild(note('albedo (linear, per channel)' + (M.albedo.present ? '' : ' — no albedo.npy: uniform')));
        break;
      case 'normals': {
        const cv = document.createElement('canvas');
        cv.width = 64; cv.height = 64; cv.style.width = '64px'; cv.style.height = '64px'; cv.style.border = '0';
        const c = cv.getContext('2d'), img = c.createImageData(64, 64);
        for (let y = 0; y < 64; y++) for (let x = 0; x < 64; x++) {
          const nx = (x + 0.5) / 32 - 1, ny = 1 - (y + 0.5) / 32, r2 = nx * nx + ny * ny, o = 4 * (y * 64 + x);
          if (r2 > 1) { img.data[o + 3] = 0; continue; }
          const nz = Math.sqrt(1 - r2);
          img.data[o] = (nx + 1) * 127.5; img.data[o + 1] = (ny + 1) * 127.5; img.data[o + 2] = (nz + 1) * 127.5; img.data[o + 3] = 255;
        }
        c.putImageData(img, 0, 0);
        el.appendChild(cv);
        el.appendChild(note('RGB = (n + 1) / 2, camera frame: x right, y up, z toward the viewer (a sphere seen from the camera).'));
        break;
      }
      case 'depth':
        el.appendChild(bar(cmapCss, M.depth.min, M.depth.max, ' ' + M.depth.unit));
        el.appendChild(note('height toward the camera, hill-shaded from the upper left'));
        break;
      case 'unreliable':
        el.appendChild(bar((t) => { const g = Math.round(255 * Math.sqrt(t)); return 'rgb(' + g + ',' + g + ',' + g + ')'; }, 0, M.residual ? M.residual.max : 1, ''));
        el.appendChild(note('non-Lambertian statistic (residual / noise), square-root grey scale'));
        el.appendChild(swatch('rgb(255,31,20)', 'unreliable (χ² test)'));
        break;
      case 'count':
        el.appendChild(bar(cmapCss, 0, NL, ''));
        el.appendChild(note('lights not used at each pixel (shadow, highlight or rejected)'));
        el.appendChild(swatch('#f0f', 'fewer than three usable lights'));
        break;
      case 'status':
        STATUS_NAMES.forEach((n, i) => el.appendChild(swatch(STATUS_COLORS[i], n)));
        el.appendChild(note('status of capture light ' + S.k + ' (slider above)'));
        break;
      case 'error':
        el.appendChild(bar(cmapCss, 0, M.error.max_deg, '°'));
        el.appendChild(note('angular error against ' + (M.error.ground_truth || 'ground truth') + '; grey: no ground truth'));
        break;
      case 'rti':
        el.appendChild(note('the ' + M.rti.basis + ' fit (' + M.rti.planes + ' planes) relit under the light, times 2^exposure; specular and shininess add a white highlight from the normals, diffuse gain (PTM) scales its curvature, unsharp sharpens the normals\' shading'));
        break;
      case 'gloss':
        el.appendChild(bar(cmapCss, 0, layerMax(), ''));
        el.appendChild(note((S.gloss === 'roughness' ? 'specular lobe roughness' : 'specular strength') + ' (grey: not fitted)'));
        break;
      case 'mesh':
        el.appendChild(note('mesh from depth, every ' + M.mesh.stride + ' px (' + M.mesh.vertices + ' vertices), lit like the relight layer; the light is fixed to the object'));
        break;
    }
  }

  // ---------------------------------------------------------------- pointer and keys
  let drag = null;
  canvas.addEventListener('contextmenu', (e) => e.preventDefault());
  canvas.addEventListener('pointerdown', (e) => {
    canvas.setPointerCapture(e.pointerId);
    const rect = canvas.getBoundingClientRect();
    const x = e.clientX - rect.left, y = e.clientY - rect.top;
    const pan = e.shiftKey || e.button !== 0;
    const mode = S.layer === 'mesh' ? (pan ? 'mesh-pan' : 'orbit') : ((S.layer === 'relight' || S.layer === 'rti') && !pan ? 'light' : 'pan');
    drag = { x, y, x0: x, y0: y, mode, moved: false };
  });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const rect = canvas.getBoundingClientRect();
    const x = e.clientX - rect.left, y = e.clientY - rect.top;
    if (Math.hypot(x - drag.x0, y - drag.y0) > 3) drag.moved = true;
    if (!drag.moved) return;
    const dx = x - drag.x, dy = y - drag.y;
    drag.x = x; drag.y = y;
    if (drag.mode === 'light') {
      const s = Math.min(canvas.clientWidth, canvas.clientHeight) / 2;
      S.light = diskToLight((x - canvas.clientWidth / 2) / s, -(y - canvas.clientHeight / 2) / s);
      syncUi();
    } else if (drag.mode === 'pan') {
      view.cx -= dx / view.zoom; view.cy -= dy / view.zoom;
      userMovedView = true;
      writeHash();
      requestDraw();
    } else if (drag.mode === 'orbit') {
      mesh.yaw -= dx * 0.01;
      mesh.pitch = Math.max(-1.5, Math.min(1.5, mesh.pitch + dy * 0.01));
      writeHash();
      requestDraw();
    } else if (drag.mode === 'mesh-pan') {
      const cam = meshCamera(), k = mesh.dist * 0.0015;
      for (let i = 0; i < 3; i++) mesh.pan[i] -= (cam.xx[i] * dx - cam.yy[i] * dy) * k;
      requestDraw();
    }
  });
  canvas.addEventListener('pointerup', (e) => {
    if (drag && !drag.moved && S.layer !== 'mesh' && e.button === 0) {
      const [ix, iy] = screenToImage(drag.x0, drag.y0);
      S.probe = [Math.floor(iy), Math.floor(ix)];
      syncUi();
    }
    drag = null;
  });
  canvas.addEventListener('dblclick', () => {
    if (S.layer === 'mesh') { mesh.yaw = 0; mesh.pitch = 0; mesh.pan = [0, 0, 0]; if (mesh.radius) mesh.dist = mesh.radius * 4.2; }
    else { S.fit = 'all'; userMovedView = false; writeHash(); }
    requestDraw();
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    const f = Math.exp(-e.deltaY * (e.deltaMode === 1 ? 0.05 : 0.0015));
    if (S.layer === 'mesh') { mesh.dist = Math.max(mesh.radius * 0.05, mesh.dist / f); requestDraw(); return; }
    const rect = canvas.getBoundingClientRect();
    const x = e.clientX - rect.left, y = e.clientY - rect.top;
    const [ix, iy] = screenToImage(x, y);
    view.zoom = Math.min(64, Math.max(1e-3, view.zoom * f));
    view.cx = ix - (x - canvas.clientWidth / 2) / view.zoom;
    view.cy = iy - (y - canvas.clientHeight / 2) / view.zoom;
    userMovedView = true;
    writeHash();
    requestDraw();
  }, { passive: false });
  window.addEventListener('keydown', (e) => {
    if (e.target && e.target.tagName === 'INPUT' && e.target.type !== 'checkbox') return;
    const l = norm3(S.light);
    let az = Math.atan2(l[1], l[0]), el = Math.asin(Math.min(1, l[2]));
    const step = 5 * Math.PI / 180;
    let handled = true;
    if (e.key === 'ArrowLeft') az += step;
    else if (e.key === 'ArrowRight') az -= step;
    else if (e.key === 'ArrowUp') el = Math.min(Math.PI / 2, el + step);
    else if (e.key === 'ArrowDown') el = Math.max(0, el - step);
    else if (e.key === 'f') { S.fit = 'all'; userMovedView = false; handled = false; requestDraw(); }
    else if (e.key === '0') { S.fit = '1:1'; userMovedView = false; handled = false; requestDraw(); }
    else if (/^[1-9]$/.test(e.key)) {
      const names = Object.keys(LAYER_INFO).filter((n) => M.layers.includes(n));
      if (names[+e.key - 1]) setLayer(names[+e.key - 1]);
      handled = false;
    } else handled = false;
    if (handled) {
      S.light = [Math.cos(az) * Math.cos(el), Math.sin(az) * Math.cos(el), Math.sin(el)];
      e.preventDefault();
      syncUi();
    }
  });
  window.addEventListener('resize', () => requestDraw());
  window.addEventListener('hashchange', () => {
    parseHash();
    if (S.zoom) { view.zoom = S.zoom; userMovedView = true; }
    if (S.center) { view.cx = S.center[0]; view.cy = S.center[1]; }
    syncUi();
  });

  // ---------------------------------------------------------------- start
  try {
    buildUi();
    resize();
    fitView(S.fit);
    if (S.zoom) { view.zoom = S.zoom; userMovedView = true; }
    if (S.center) { view.cx = S.center[0]; view.cy = S.center[1]; userMovedView = true; }
    imageProgram(S.layer === 'mesh' ? 'relight' : S.layer);
    // The reduced level first: the whole image, one tile, for the current layer.
    for (const g of LAYER_INFO[S.layer === 'mesh' ? 'relight' : S.layer].groups) want(TOP, 0, 0, g, false);
    pump();
    syncUi();
  } catch (err) {
    fail('Viewer failed to start: ' + (err.message || err));
  }
})();
