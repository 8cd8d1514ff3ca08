// geovox HTML viewer: decodes the volume embedded in this page and ray-marches it with WebGL2.
// Nothing is loaded from outside the page. Test hooks: window.geovoxViewer (see the README).
(function () {
  "use strict";

  const body = document.body;
  const $ = (id) => document.getElementById(id);

  function fail(message) {
    const text = String(message);
    if (!body.dataset.error) body.dataset.error = text;
    const box = $("gv-error");
    box.textContent = "geovox viewer: " + text;
    box.hidden = false;
  }
  window.addEventListener("error", (e) => fail(e.message || "script error"));
  window.addEventListener("unhandledrejection", (e) => fail((e.reason && e.reason.message) || e.reason));

  // ---- decoding -----------------------------------------------------------------------------
  async function inflate(id) {
    const el = document.getElementById(id);
    const bin = atob(el.textContent.trim());
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    if (typeof DecompressionStream === "undefined") {
      throw new Error("this browser has no DecompressionStream (needed to unpack the volume)");
    }
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
    return new Uint8Array(await new Response(stream).arrayBuffer());
  }

  function typed(bytes, dtype) {
    const buf = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
    if (dtype === "uint8") return new Uint8Array(buf);
    if (dtype === "uint16") return new Uint16Array(buf);
    if (dtype === "float32") return new Float32Array(buf);
    throw new Error("unknown dtype " + dtype);
  }

  async function decode(meta) {
    const n = meta.shape[0] * meta.shape[1] * meta.shape[2];
    const out = {};
    for (const name of Object.keys(meta.fields)) {
      let bytes;
      try {
        bytes = await inflate("geovox-field-" + name);
      } catch (err) {
        throw new Error("cannot unpack the embedded " + name + " (" + err.message + ")");
      }
      const dtype = meta.fields[name].dtype;
      if (dtype === "bits") {
        const occ = new Uint8Array(n);
        for (let i = 0; i < n; i++) occ[i] = (bytes[i >> 3] >> (i & 7)) & 1;
        out[name] = occ;
      } else {
        out[name] = typed(bytes, dtype);
      }
      const want = name === "colors" ? 4 * n : n;
      if (out[name].length !== want) throw new Error("the embedded " + name + " has the wrong size");
    }
    return out;
  }

  // ---- small matrix helpers (column-major, as WebGL wants) ---------------------------------
  const V = {
    sub: (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]],
    add: (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]],
    mul: (a, s) => [a[0] * s, a[1] * s, a[2] * s],
    dot: (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2],
    cross: (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]],
    norm: (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; },
  };

  function perspective(fovy, aspect, near, far) {
    const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
  }

  function lookAt(eye, target, up) {
    const z = V.norm(V.sub(eye, target)), x = V.norm(V.cross(up, z)), y = V.cross(z, x);
    return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
      -V.dot(x, eye), -V.dot(y, eye), -V.dot(z, eye), 1];
  }

  function multiply(a, b) {
    const o = new Array(16);
    for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      o[c * 4 + r] = s;
    }
    return o;
  }

  function invert(m) {
    const inv = new Array(16);
    inv[0] = m[5] * m[10] * m[15] - m[5] * m[11] * m[14] - m[9] * m[6] * m[15] + m[9] * m[7] * m[14] + m[13] * m[6] * m[11] - m[13] * m[7] * m[10];
    inv[4] = -m[4] * m[10] * m[15] + m[4] * m[11] * m[14] + m[8] * m[6] * m[15] - m[8] * m[7] * m[14] - m[12] * m[6] * m[11] + m[12] * m[7] * m[10];
    inv[8] = m[4] * m[9] * m[15] - m[4] * m[11] * m[13] - m[8] * m[5] * m[15] + m[8] * m[7] * m[13] + m[12] * m[5] * m[11] - m[12] * m[7] * m[9];
    inv[12] = -m[4] * m[9] * m[14] + m[4] * m[10] * m[13] + m[8] * m[5] * m[14] - m[8] * m[6] * m[13] - m[12] * m[5] * m[10] + m[12] * m[6] * m[9];
    inv[1] = -m[1] * m[10] * m[15] + m[1] * m[11] * m[14] + m[9] * m[2] * m[15] - m[9] * m[3] * m[14] - m[13] * m[2] * m[11] + m[13] * m[3] * m[10];
    inv[5] = m[0] * m[10] * m[15] - m[0] * m[11] * m[14] - m[8] * m[2] * m[15] + m[8] * m[3] * m[14] + m[12] * m[2] * m[11] - m[12] * m[3] * m[10];
    inv[9] = -m[0] * m[9] * m[15] + m[0] * m[11] * m[13] + m[8] * m[1] * m[15] - m[8] * m[3] * m[13] - m[12] * m[1] * m[11] + m[12] * m[3] * m[9];
    inv[13] = m[0] * m[9] * m[14] - m[0] * m[10] * m[13] - m[8] * m[1] * m[14] + m[8] * m[2] * m[13] + m[12] * m[1] * m[10] - m[12] * m[2] * m[9];
    inv[2] = m[1] * m[6] * m[15] - m[1] * m[7] * m[14] - m[5] * m[2] * m[15] + m[5] * m[3] * m[14] + m[13] * m[2] * m[7] - m[13] * m[3] * m[6];
    inv[6] = -m[0] * m[6] * m[15] + m[0] * m[7] * m[14] + m[4] * m[2] * m[15] - m[4] * m[3] * m[14] - m[12] * m[2] * m[7] + m[12] * m[3] * m[6];
    inv[10] = m[0] * m[5] * m[15] - m[0] * m[7] * m[13] - m[4] * m[1] * m[15] + m[4] * m[3] * m[13] + m[12] * m[1] * m[7] - m[12] * m[3] * m[5];
    inv[14] = -m[0] * m[5] * m[14] + m[0] * m[6] * m[13] + m[4] * m[1] * m[14] - m[4] * m[2] * m[13] - m[12] * m[1] * m[6] + m[12] * m[2] * m[5];
    inv[3] = -m[1] * m[6] * m[11] + m[1] * m[7] * m[10] + m[5] * m[2] * m[11] - m[5] * m[3] * m[10] - m[9] * m[2] * m[7] + m[9] * m[3] * m[6];
    inv[7] = m[0] * m[6] * m[11] - m[0] * m[7] * m[10] - m[4] * m[2] * m[11] + m[4] * m[3] * m[10] + m[8] * m[2] * m[7] - m[8] * m[3] * m[6];
    inv[11] = -m[0] * m[5] * m[11] + m[0] * m[7] * m[9] + m[4] * m[1] * m[11] - m[4] * m[3] * m[9] - m[8] * m[1] * m[7] + m[8] * m[3] * m[5];
    inv[15] = m[0] * m[5] * m[10] - m[0] * m[6] * m[9] - m[4] * m[1] * m[10] + m[4] * m[2] * m[9] + m[8] * m[1] * m[6] - m[8] * m[2] * m[5];
    const det = m[0] * inv[0] + m[1] * inv[4] + m[2] * inv[8] + m[3] * inv[12];
    return inv.map((v) => v / det);
  }

  // ---- volumes on the CPU: fields, smoothing, label colours --------------------------------
  // [1 2 1] along each axis in integers: 255 becomes 255 * 64 after three passes (fits uint16).
  function smooth(src, nx, ny, nz) {
    let a = new Uint16Array(src), b = new Uint16Array(src.length);
    const dims = [nx, ny, nz], strides = [1, nx, nx * ny];
    for (let axis = 0; axis < 3; axis++) {
      const n = dims[axis], s = strides[axis];
      for (let z = 0; z < nz; z++) for (let y = 0; y < ny; y++) {
        const row = z * nx * ny + y * nx;
        for (let x = 0; x < nx; x++) {
          const i = row + x, c = axis === 0 ? x : axis === 1 ? y : z;
          b[i] = (c > 0 ? a[i - s] : a[i]) + 2 * a[i] + (c < n - 1 ? a[i + s] : a[i]);
        }
      }
      const t = a; a = b; b = t;
    }
    const out = new Uint8Array(src.length);
    for (let i = 0; i < out.length; i++) out[i] = a[i] >> 6;
    return out;
  }

  // Max of the field over each BLOCK³ block widened by a voxel on every side (what trilinear
  // samples inside the block read): a block whose max is below the threshold is skipped whole.
  const BLOCK = 8;
  function coarseMax(src, dims) {
    let cur = src, shape = dims.slice();
    for (let axis = 0; axis < 3; axis++) {
      const n = shape[axis], c = Math.ceil(n / BLOCK);
      const out = shape.slice(); out[axis] = c;
      const dst = new Uint8Array(out[0] * out[1] * out[2]);
      const sIn = [1, shape[0], shape[0] * shape[1]], sOut = [1, out[0], out[0] * out[1]];
      const [a1, a2] = [0, 1, 2].filter((a) => a !== axis);
      for (let j = 0; j < shape[a2]; j++) for (let i = 0; i < shape[a1]; i++) {
        const baseIn = i * sIn[a1] + j * sIn[a2], baseOut = i * sOut[a1] + j * sOut[a2];
        for (let b = 0; b < c; b++) {
          let m = 0;
          const lo = Math.max(0, b * BLOCK - 1), hi = Math.min(n - 1, b * BLOCK + BLOCK);
          for (let x = lo; x <= hi; x++) { const v = cur[baseIn + x * sIn[axis]]; if (v > m) m = v; }
          dst[baseOut + b * sOut[axis]] = m;
        }
      }
      cur = dst; shape = out;
    }
    return { data: cur, shape };
  }

  function autoColour(value) {
    const h = (value * 137.508) % 360, s = 0.65, l = 0.55;
    const k = (n) => (n + h / 30) % 12, a = s * Math.min(l, 1 - l);
    const f = (n) => l - a * Math.max(-1, Math.min(k(n) - 3, 9 - k(n), 1));
    return [Math.round(255 * f(0)), Math.round(255 * f(8)), Math.round(255 * f(4)), 255];
  }

  function labelModel(meta, labels) {
    const size = labels instanceof Uint16Array ? 65536 : 256;
    const counts = new Uint32Array(size);
    for (let i = 0; i < labels.length; i++) counts[labels[i]]++;
    const entries = new Map();
    for (const e of meta.label_table) entries.set(e.value, { value: e.value, name: e.name, color: e.color });
    for (let v = 1; v < size; v++) {
      if (counts[v] && !entries.has(v)) entries.set(v, { value: v, name: "label " + v, color: autoColour(v) });
    }
    const list = [...entries.values()].filter((e) => e.value < size).sort((p, q) => p.value - q.value);
    for (const e of list) { e.count = counts[e.value]; e.visible = true; }
    const lut = new Uint8Array(size * 4);
    for (const e of list) lut.set(e.color.slice(0, 3).concat([255]), e.value * 4);
    const rgba = new Uint8Array(labels.length * 4);
    for (let i = 0; i < labels.length; i++) {
      const o = labels[i] * 4;
      if (o) { rgba[4 * i] = lut[o]; rgba[4 * i + 1] = lut[o + 1]; rgba[4 * i + 2] = lut[o + 2]; rgba[4 * i + 3] = 255; }
    }
    return { list, lut, rgba, size };
  }

  function gl3D(gl, t, shape, bytes) {
    gl.bindTexture(gl.TEXTURE_3D, t);
    gl.texParameteri(gl.TEXTURE_3D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_3D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.R8, shape[0], shape[1], shape[2], 0, gl.RED, gl.UNSIGNED_BYTE, bytes);
  }

  // ---- the viewer ---------------------------------------------------------------------------
  class Viewer {
    constructor(meta, data) {
      this.meta = meta;
      this.data = data;
      this.shape = meta.shape;
      this.f = meta.factor;
      const full = meta.shape.map((m, i) => m * meta.shown_spacing[i]);
      const longest = Math.max(...full);
      this.worldLongest = longest;
      this.ext = full.map((e) => e / longest);
      this.clip = { lo: [0, 0, 0], hi: meta.original_shape.slice() };
      this.frames = 0;
      this.labels = data.labels ? labelModel(meta, data.labels) : null;
      this.modes = [];
      if (this.labels) this.modes.push(["labels", "labels"]);
      this.modes.push(["occupancy", data.colors ? "occupancy, in colour" : "occupancy"]);
      if (data.sdf) this.modes.push(["sdf", "distance (iso-surface)"]);
      if (data.density) this.modes.push(["density", "density (fog)"]);
      this.mode = this.modes[0][0];
      this.iso = 0;
      this.opacity = 0.4;
      this.up = "y";
      this.showBox = true;
      this.showSlices = false;
      this.dragScale = 1;
      this.initGL();
      this.resetCamera(false);
      this.buildField();
      this.initUI();
    }

    initGL() {
      const canvas = $("gv-canvas");
      this.canvas = canvas;
      const gl = canvas.getContext("webgl2", { antialias: false, alpha: false, preserveDrawingBuffer: false });
      if (!gl) throw new Error("this browser cannot show the volume: WebGL2 is not available");
      this.gl = gl;
      const most = gl.getParameter(gl.MAX_3D_TEXTURE_SIZE);
      if (Math.max(...this.shape) > most) {
        throw new Error("this GPU holds 3D textures of at most " + most + " voxels a side; the page has " +
          this.shape.join(" x ") + ": write it again with geovox view --html --max-side " + most);
      }
      const compile = (type, id) => {
        const s = gl.createShader(type);
        gl.shaderSource(s, $(id).textContent.trim());
        gl.compileShader(s);
        if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(s));
        return s;
      };
      const prog = gl.createProgram();
      gl.attachShader(prog, compile(gl.VERTEX_SHADER, "geovox-vertex"));
      gl.attachShader(prog, compile(gl.FRAGMENT_SHADER, "geovox-fragment"));
      gl.linkProgram(prog);
      if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("shader link: " + gl.getProgramInfoLog(prog));
      this.prog = prog;
      this.u = {};
      const n = gl.getProgramParameter(prog, gl.ACTIVE_UNIFORMS);
      for (let i = 0; i < n; i++) {
        const name = gl.getActiveUniform(prog, i).name;
        this.u[name] = gl.getUniformLocation(prog, name);
      }
      gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
      this.vao = gl.createVertexArray();
      const [mx, my, mz] = this.shape;
      const tex = (format, internal, linear, bytes) => {
        const t = gl.createTexture();
        gl.bindTexture(gl.TEXTURE_3D, t);
        const filter = linear ? gl.LINEAR : gl.NEAREST;
        gl.texParameteri(gl.TEXTURE_3D, gl.TEXTURE_MIN_FILTER, filter);
        gl.texParameteri(gl.TEXTURE_3D, gl.TEXTURE_MAG_FILTER, filter);
        for (const w of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T, gl.TEXTURE_WRAP_R]) gl.texParameteri(gl.TEXTURE_3D, w, gl.CLAMP_TO_EDGE);
        gl.texImage3D(gl.TEXTURE_3D, 0, internal, mx, my, mz, 0, format, gl.UNSIGNED_BYTE, bytes);
        return t;
      };
      this.texField = tex(gl.RED, gl.R8, true, null);
      this.texCoarse = gl.createTexture();
      this.texSmooth = tex(gl.RED, gl.R8, true, null);
      this.texColor = this.data.colors ? tex(gl.RGBA, gl.RGBA8, false, this.data.colors) : null;
      this.texLabels = this.labels ? tex(gl.RGBA, gl.RGBA8, false, this.labels.rgba) : null;
      this.upload = (t, bytes) => {
        gl.bindTexture(gl.TEXTURE_3D, t);
        gl.texSubImage3D(gl.TEXTURE_3D, 0, 0, 0, 0, mx, my, mz, gl.RED, gl.UNSIGNED_BYTE, bytes);
      };
    }

    // The scalar the surface is found in, for the current mode: uField and uSmooth.
    buildField() {
      const [mx, my, mz] = this.shape, n = mx * my * mz, d = this.data;
      const field = new Uint8Array(n);
      let smoothIt = true;
      if (this.mode === "labels") {
        const vis = new Uint8Array(this.labels.size);
        for (const e of this.labels.list) vis[e.value] = e.visible ? 255 : 0;
        const lab = d.labels;
        for (let i = 0; i < n; i++) field[i] = vis[lab[i]];
      } else if (this.mode === "sdf") {
        const r = Math.max(Math.abs(this.meta.fields.sdf.range[0]), Math.abs(this.meta.fields.sdf.range[1])) || 1;
        this.sdfRange = r;
        for (let i = 0; i < n; i++) field[i] = Math.max(0, Math.min(255, Math.round(255 * (0.5 - d.sdf[i] / (2 * r)))));
        smoothIt = false;
      } else if (this.mode === "density") {
        const dmax = d.density instanceof Uint8Array ? 255 : Math.max(this.meta.fields.density.max, 1e-30);
        for (let i = 0; i < n; i++) field[i] = Math.max(0, Math.min(255, Math.round(255 * d.density[i] / dmax)));
        smoothIt = false;
      } else {
        for (let i = 0; i < n; i++) field[i] = d.occupancy[i] * 255;
      }
      this.upload(this.texField, field);
      const coarse = coarseMax(field, this.shape);
      gl3D(this.gl, this.texCoarse, coarse.shape, coarse.data);
      // Twice: a 5-voxel kernel, so that the normals of a voxel staircase turn smoothly.
      this.upload(this.texSmooth, smoothIt ? smooth(smooth(field, mx, my, mz), mx, my, mz) : field);
      this.fieldBytes = field;
    }

    threshold() {
      if (this.mode === "sdf") return 0.5 - this.iso / (2 * this.sdfRange);
      return 0.5;
    }

    resetCamera(render = true) {
      this.yaw = -2.6;
      this.pitch = 0.35;
      this.dist = 2.9;
      this.target = [0, 0, 0];
      if (render) this.requestRender();
    }

    basis() {
      return this.up === "z"
        ? { U: [0, 0, 1], F: [0, -1, 0], R: [1, 0, 0] }
        : { U: [0, 1, 0], F: [0, 0, 1], R: [1, 0, 0] };
    }

    camera() {
      const { U, F, R } = this.basis();
      const cp = Math.cos(this.pitch), sp = Math.sin(this.pitch);
      const off = V.add(V.add(V.mul(R, cp * Math.sin(this.yaw)), V.mul(F, cp * Math.cos(this.yaw))), V.mul(U, sp));
      const eye = V.add(this.target, V.mul(off, this.dist));
      return { eye, up: U };
    }

    resize(scale) {
      const dpr = Math.min(window.devicePixelRatio || 1, 2) * scale;
      const w = Math.max(1, Math.round(this.canvas.clientWidth * dpr));
      const h = Math.max(1, Math.round(this.canvas.clientHeight * dpr));
      if (this.canvas.width !== w || this.canvas.height !== h) { this.canvas.width = w; this.canvas.height = h; }
    }

    draw() {
      const gl = this.gl, u = this.u;
      this.resize(this.dragging ? this.dragScale : 1);
      gl.viewport(0, 0, this.canvas.width, this.canvas.height);
      const fov = 35 * Math.PI / 180, aspect = this.canvas.width / this.canvas.height;
      const { eye, up } = this.camera();
      const view = lookAt(eye, this.target, up);
      const proj = perspective(fov, aspect, 0.01, 100);
      gl.useProgram(this.prog);
      gl.uniformMatrix4fv(u.uInvViewProj, false, invert(multiply(proj, view)));
      gl.uniform3fv(u.uEye, eye);
      gl.uniform3fv(u.uExt, this.ext);
      gl.uniform3fv(u.uShape, this.shape);
      const tlo = [0, 1, 2].map((i) => this.clip.lo[i] / (this.shape[i] * this.f));
      const thi = [0, 1, 2].map((i) => this.clip.hi[i] / (this.shape[i] * this.f));
      gl.uniform3fv(u.uClipLo, tlo);
      gl.uniform3fv(u.uClipHi, thi);
      gl.uniform1f(u.uThreshold, this.threshold());
      gl.uniform1i(u.uMode, this.mode === "density" ? 1 : 0);
      const colourTex = this.mode === "labels" ? this.texLabels : this.texColor;
      gl.uniform1i(u.uHasColor, colourTex ? 1 : 0);
      gl.uniform3fv(u.uBaseColor, [0.8, 0.8, 0.78]);
      gl.uniform1f(u.uOpacity, this.opacity);
      gl.uniform3fv(u.uBg, [0.114, 0.125, 0.149]);
      gl.uniform1i(u.uShowBox, this.showBox ? 1 : 0);
      gl.uniform1f(u.uPixel, 2 * Math.tan(fov / 2) / this.canvas.height);
      const fwd = V.norm(V.sub(this.target, eye)), right = V.norm(V.cross(fwd, up)), camUp = V.cross(right, fwd);
      const light = (r, uu, b) => V.norm(V.add(V.add(V.mul(right, r), V.mul(camUp, uu)), V.mul(fwd, -b)));
      gl.uniform3fv(u.uLight1, light(-0.4, 0.5, 0.9));
      gl.uniform3fv(u.uLight2, light(0.7, -0.2, 0.4));
      const bind = (unit, tex, name) => {
        gl.activeTexture(gl.TEXTURE0 + unit);
        gl.bindTexture(gl.TEXTURE_3D, tex);
        gl.uniform1i(u[name], unit);
      };
      bind(0, this.texField, "uField");
      bind(1, this.texSmooth, "uSmooth");
      bind(2, colourTex || this.texField, "uColor");
      bind(3, this.texCoarse, "uCoarse");
      gl.uniform1i(u.uShowSlices, this.showSlices ? 1 : 0);
      gl.uniform3fv(u.uSlice, (this.slice || [0, 0, 0]).map((k, i) => (k + 0.5) / this.shape[i]));
      gl.uniform1f(u.uSkipBelow, this.mode === "density" ? 0.003 : this.threshold());
      gl.bindVertexArray(this.vao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      this.frames++;
      this.updateScaleBar(fov);
    }

    requestRender() {
      if (this.pending) return;
      this.pending = true;
      requestAnimationFrame((now) => {
        this.pending = false;
        // While the camera moves, fewer pixels when frames come slower than about 30 a second
        // (the browser paces animation frames to what the GPU finishes), more when faster.
        if (this.dragging && this.lastFrame !== undefined) {
          const dt = now - this.lastFrame;
          if (dt > 45) this.dragScale = Math.max(0.3, this.dragScale * 0.75);
          else if (dt < 22) this.dragScale = Math.min(1, this.dragScale * 1.1);
        }
        this.lastFrame = this.dragging ? now : undefined;
        this.draw();
        if (!body.dataset.rendered) {
          const px = new Uint8Array(4);
          this.gl.readPixels(0, 0, 1, 1, this.gl.RGBA, this.gl.UNSIGNED_BYTE, px);  // waits for the frame
          body.dataset.rendered = "1";
        }
      });
    }

    updateScaleBar(fov) {
      const pxPerUnit = this.canvas.clientHeight / (2 * this.dist * Math.tan(fov / 2)) / this.worldLongest;
      const want = 110 / pxPerUnit, p = Math.pow(10, Math.floor(Math.log10(want)));
      const nice = [5, 2, 1].map((k) => k * p).find((v) => v <= want) || p;
      $("gv-scale-bar").style.width = Math.round(nice * pxPerUnit) + "px";
      $("gv-scale-label").textContent = fmt(nice) + " (model units, at the centre)";
    }

    boundsText() {
      const lo = this.meta.bounds[0], sp = this.meta.spacing;
      const vals = [];
      for (const side of ["lo", "hi"]) for (let i = 0; i < 3; i++) vals.push(lo[i] + this.clip[side][i] * sp[i]);
      const dec = Math.max(0, Math.ceil(-Math.log10(Math.min(...sp))) + 2);
      return "--bounds " + vals.map((v) => String(Number(v.toFixed(Math.min(dec, 12))))).join(" ");
    }

    setClip(lo, hi) {
      const n = this.meta.original_shape;
      for (let i = 0; i < 3; i++) {
        const a = Math.round(Math.max(0, Math.min(1, lo[i])) * n[i]);
        const b = Math.round(Math.max(0, Math.min(1, hi[i])) * n[i]);
        this.clip.lo[i] = Math.min(a, n[i] - 1);
        this.clip.hi[i] = Math.max(b, this.clip.lo[i] + 1);
      }
      this.syncClipUI();
      this.requestRender();
      return this.boundsText();
    }

    syncClipUI() {
      for (let i = 0; i < 3; i++) {
        $("gv-clip-lo-" + i).value = this.clip.lo[i];
        $("gv-clip-hi-" + i).value = this.clip.hi[i];
      }
      $("gv-bounds").value = this.boundsText();
    }

    setMode(mode) {
      if (!this.modes.some((m) => m[0] === mode)) throw new Error("no such mode here: " + mode);
      this.mode = mode;
      $("gv-mode").value = mode;
      $("gv-iso-row").hidden = mode !== "sdf";
      $("gv-opacity-row").hidden = mode !== "density";
      this.buildField();
      this.drawSlices();
      this.requestRender();
    }

    toggleLabel(value, visible) {
      const e = this.labels && this.labels.list.find((x) => x.value === value);
      if (!e) throw new Error("no label " + value);
      e.visible = visible === undefined ? !e.visible : !!visible;
      const box = document.querySelector('#gv-legend input[data-value="' + value + '"]');
      if (box) box.checked = e.visible;
      if (this.mode !== "labels") this.setMode("labels");
      else { this.buildField(); this.drawSlices(); this.requestRender(); }
      return e.visible;
    }

    snapshot() {
      this.draw();
      return this.canvas.toDataURL("image/png");
    }

    initUI() { initPanel(this); initMouse(this); }

    drawSlices() { for (let a = 0; a < 3; a++) drawSlice(this, a); }
  }

  function fmt(v) {
    if (v === 0) return "0";
    const a = Math.abs(v);
    if (a >= 1e5 || a < 1e-3) return v.toExponential(3);
    return String(Number(v.toPrecision(6)));
  }

  // ---- the panel ---------------------------------------------------------------------------
  function initPanel(vw) {
    const m = vw.meta;
    $("gv-title").textContent = m.source || "volume";
    const rows = [
      ["source", m.source_path || "-"],
      ["grid", m.original_shape.join(" × ") + " voxels"],
      ["voxel", m.spacing.map(fmt).join(" × ")],
      ["inside", m.inside_count.toLocaleString("en") + " voxels (" +
        (100 * m.inside_count / m.original_shape.reduce((a, b) => a * b, 1)).toFixed(1) + " %)"],
      ["bounds", m.bounds[0].map(fmt).join(", ") + " to " + m.bounds[1].map(fmt).join(", ")],
      ["fields", Object.keys(m.fields).join(", ")],
    ];
    if (m.factor > 1) {
      rows.push(["shown", m.shape.join(" × ") + " (downsampled ×" + m.factor + ")"]);
      const b = $("gv-banner");
      b.textContent = "Downsampled by " + m.factor + " on every axis to " + m.shape.join(" × ") +
        " for the browser (occupancy: max, colour: alpha-weighted mean, labels: nearest). " +
        "The clipping box and --bounds use the full " + m.original_shape.join(" × ") + " grid.";
      b.hidden = false;
    }
    $("gv-info").innerHTML = "";
    for (const [k, v] of rows) {
      const tr = document.createElement("tr");
      for (const t of [k, v]) { const td = document.createElement("td"); td.textContent = t; tr.appendChild(td); }
      $("gv-info").appendChild(tr);
    }
    const mode = $("gv-mode");
    for (const [value, label] of vw.modes) mode.add(new Option(label, value));
    mode.value = vw.mode;
    mode.onchange = () => vw.setMode(mode.value);
    $("gv-up").onchange = (e) => { vw.up = e.target.value; vw.requestRender(); };
    $("gv-showbox").onchange = (e) => { vw.showBox = e.target.checked; vw.requestRender(); };
    $("gv-showslices").onchange = (e) => { vw.showSlices = e.target.checked; vw.requestRender(); };
    $("gv-reset-camera").onclick = () => vw.resetCamera();
    initSliders(vw);
    initClip(vw);
    if (vw.labels) initLegend(vw);
    initSlices(vw);
    vw.setMode(vw.mode);
  }

  function initSliders(vw) {
    const iso = $("gv-iso"), op = $("gv-opacity");
    if (vw.data.sdf) {
      const r = vw.meta.fields.sdf.range;
      iso.oninput = () => {
        vw.iso = r[0] + (r[1] - r[0]) * iso.value / 1000;
        $("gv-iso-value").textContent = fmt(Number(vw.iso.toPrecision(3)));
        vw.requestRender();
      };
      iso.value = Math.round(1000 * (0 - r[0]) / ((r[1] - r[0]) || 1));
      iso.oninput();
    }
    op.oninput = () => { vw.opacity = op.value / 1000; $("gv-opacity-value").textContent = vw.opacity.toFixed(2); vw.requestRender(); };
    op.oninput();
  }

  function initClip(vw) {
    const box = $("gv-clip"), n = vw.meta.original_shape;
    for (let i = 0; i < 3; i++) {
      const row = document.createElement("div");
      row.className = "gv-clip-axis";
      row.innerHTML = "<b>" + "xyz"[i] + "</b>";
      for (const side of ["lo", "hi"]) {
        const s = document.createElement("input");
        s.type = "range"; s.min = 0; s.max = n[i]; s.step = 1; s.id = "gv-clip-" + side + "-" + i;
        s.title = side === "lo" ? "low side" : "high side";
        s.oninput = () => {
          let v = Number(s.value);
          if (side === "lo") vw.clip.lo[i] = Math.min(v, vw.clip.hi[i] - 1);
          else vw.clip.hi[i] = Math.max(v, vw.clip.lo[i] + 1);
          vw.syncClipUI();
          vw.requestRender();
        };
        row.appendChild(s);
      }
      box.appendChild(row);
    }
    $("gv-reset-clip").onclick = () => vw.setClip([0, 0, 0], [1, 1, 1]);
    $("gv-copy").onclick = () => {
      const text = $("gv-bounds").value, done = () => { $("gv-copied").textContent = "copied"; setTimeout(() => { $("gv-copied").textContent = ""; }, 1500); };
      if (navigator.clipboard && window.isSecureContext) navigator.clipboard.writeText(text).then(done, () => legacyCopy(done));
      else legacyCopy(done);
    };
    vw.syncClipUI();
  }

  function legacyCopy(done) {
    const input = $("gv-bounds");
    input.select();
    try { if (document.execCommand("copy")) done(); } catch (err) { /* the text stays selected to copy by hand */ }
  }

  function initLegend(vw) {
    $("gv-labels-section").hidden = false;
    const legend = $("gv-legend");
    for (const e of vw.labels.list) {
      const row = document.createElement("label");
      row.className = "gv-label";
      const box = document.createElement("input");
      box.type = "checkbox"; box.checked = true; box.dataset.value = e.value;
      box.onchange = () => vw.toggleLabel(e.value, box.checked);
      const sw = document.createElement("span");
      sw.className = "gv-swatch";
      sw.style.background = "rgb(" + e.color.slice(0, 3).join(",") + ")";
      const name = document.createElement("span");
      name.textContent = e.name + " (" + e.value + ")";
      const count = document.createElement("span");
      count.className = "gv-count";
      count.textContent = e.count.toLocaleString("en");
      row.append(box, sw, name, count);
      legend.appendChild(row);
    }
    const all = (v) => { for (const e of vw.labels.list) e.visible = v; for (const b of legend.querySelectorAll("input")) b.checked = v; vw.setMode("labels"); };
    $("gv-labels-all").onclick = () => all(true);
    $("gv-labels-none").onclick = () => all(false);
  }

  // ---- slices ------------------------------------------------------------------------------
  function initSlices(vw) {
    vw.slice = vw.shape.map((m) => Math.floor(m / 2));
    const root = $("gv-slices");
    for (let a = 0; a < 3; a++) {
      const div = document.createElement("div");
      div.className = "gv-slice";
      const label = document.createElement("label");
      label.className = "gv-row";
      const name = document.createElement("span");
      name.style.textAlign = "left";
      name.style.whiteSpace = "nowrap";
      name.style.minWidth = "80px";
      const s = document.createElement("input");
      s.type = "range"; s.min = 0; s.max = vw.shape[a] - 1; s.value = vw.slice[a]; s.id = "gv-slice-" + a;
      s.oninput = () => { vw.slice[a] = Number(s.value); drawSlice(vw, a); if (vw.showSlices) vw.requestRender(); };
      label.append(name, s);
      const c = document.createElement("canvas");
      c.id = "gv-slice-canvas-" + a;
      div.append(label, c);
      root.appendChild(div);
    }
  }

  function drawSlice(vw, a) {
    const [mx, my, mz] = vw.shape, d = vw.data, k = vw.slice[a];
    const [u, v] = a === 0 ? [1, 2] : a === 1 ? [0, 2] : [0, 1];
    const w = vw.shape[u], h = vw.shape[v];
    const c = $("gv-slice-canvas-" + a);
    c.width = w; c.height = h;
    const scale = Math.max(1, Math.floor(280 / Math.max(w, h)));
    c.style.width = w * scale + "px";
    const ctx = c.getContext("2d"), img = ctx.createImageData(w, h), px = img.data;
    const colour = vw.mode === "labels" ? vw.labels.rgba : d.colors;
    const vis = vw.mode === "labels" ? vw.fieldBytes : null;
    const r = vw.sdfRange || 1;
    for (let j = 0; j < h; j++) for (let i = 0; i < w; i++) {
      const idx = [0, 0, 0]; idx[a] = k; idx[u] = i; idx[v] = j;
      const n = idx[0] + mx * (idx[1] + my * idx[2]), o = 4 * ((h - 1 - j) * w + i);
      let rgb;
      if (vw.mode === "sdf") {
        const s = Math.max(-1, Math.min(1, d.sdf[n] / r));
        rgb = s < 0 ? [255 * (1 + s * 0.2), 255 * (1 + s), 255 * (1 + s)] : [255 * (1 - s), 255 * (1 - s), 255];
      } else if (vw.mode === "density") {
        const g = vw.fieldBytes[n]; rgb = [g, g, g];
      } else if (vis ? vis[n] : d.occupancy[n]) {
        rgb = colour ? [colour[4 * n], colour[4 * n + 1], colour[4 * n + 2]] : [220, 220, 215];
      } else rgb = [17, 17, 17];
      px[o] = rgb[0]; px[o + 1] = rgb[1]; px[o + 2] = rgb[2]; px[o + 3] = 255;
    }
    ctx.putImageData(img, 0, 0);
    const name = c.previousSibling.firstChild;
    name.textContent = "xyz"[a] + " " + k + " / " + vw.shape[a];
    name.title = "xyz"[u] + " to the right, " + "xyz"[v] + " up";
    void mz;
  }

  // ---- mouse -------------------------------------------------------------------------------
  function initMouse(vw) {
    const c = vw.canvas;
    let last = null, panning = false;
    c.addEventListener("contextmenu", (e) => e.preventDefault());
    c.addEventListener("pointerdown", (e) => {
      c.setPointerCapture(e.pointerId);
      last = [e.clientX, e.clientY];
      panning = e.button === 2 || e.shiftKey || e.button === 1;
      vw.dragging = true;
    });
    c.addEventListener("pointermove", (e) => {
      if (!last) return;
      const dx = e.clientX - last[0], dy = e.clientY - last[1];
      last = [e.clientX, e.clientY];
      if (panning) {
        const { eye, up } = vw.camera();
        const fwd = V.norm(V.sub(vw.target, eye)), right = V.norm(V.cross(fwd, up)), camUp = V.cross(right, fwd);
        const s = vw.dist * 0.0016;
        vw.target = V.add(vw.target, V.add(V.mul(right, -dx * s), V.mul(camUp, dy * s)));
      } else {
        vw.yaw -= dx * 0.008;
        vw.pitch = Math.max(-1.55, Math.min(1.55, vw.pitch + dy * 0.008));
      }
      vw.requestRender();
    });
    const end = () => { last = null; vw.dragging = false; vw.requestRender(); };
    c.addEventListener("pointerup", end);
    c.addEventListener("pointercancel", end);
    c.addEventListener("wheel", (e) => {
      e.preventDefault();
      vw.dist = Math.max(0.3, Math.min(20, vw.dist * Math.exp(e.deltaY * 0.0012)));
      vw.requestRender();
    }, { passive: false });
    window.addEventListener("resize", () => vw.requestRender());
  }

  // ---- start -------------------------------------------------------------------------------
  async function start() {
    const meta = JSON.parse($("geovox-meta").textContent);
    const data = await decode(meta);
    const vw = new Viewer(meta, data);
    Object.assign(window.geovoxViewer, {
      viewer: vw,
      meta,
      setClip: (lo, hi) => vw.setClip(lo, hi),
      boundsText: () => vw.boundsText(),
      toggleLabel: (value, visible) => vw.toggleLabel(value, visible),
      setMode: (mode) => vw.setMode(mode),
      setIso: (level) => { vw.iso = level; vw.requestRender(); },
      setOpacity: (o) => { vw.opacity = o; vw.requestRender(); },
      setCamera: (cam) => { Object.assign(vw, cam); vw.requestRender(); },
      resetCamera: () => vw.resetCamera(),
      setSlice: (axis, index) => { vw.slice[axis] = index; $("gv-slice-" + axis).value = index; drawSlice(vw, axis); vw.requestRender(); },
      showSlices: (on) => { vw.showSlices = !!on; $("gv-showslices").checked = vw.showSlices; vw.requestRender(); },
      snapshot: () => vw.snapshot(),
      frames: () => vw.frames,
    });
    vw.requestRender();
    return vw;
  }

  window.geovoxViewer = {};
  window.geovoxViewer.ready = start().catch((err) => { fail(err.message || err); throw err; });
  window.geovoxViewer.ready.catch(() => {});
})();
