// corpuscle live viewer: WebGL2, no dependencies. Wire format: corpuscle/live/protocol.py.
'use strict';
(function () {
  const $ = (id) => document.getElementById(id);
  const S = {  // the page's state (tests read window.corpuscleViewer)
    ready: false, mode: null, hello: null, header: null, dim: 3, framesReceived: 0, frame: null,
    lastIndex: -1, lastStep: -1, errors: [], control: null, paused: false,
    playing: false, pending: false, speed: 1, nFrames: 0,
    cam: { az: 0.6, el: 0.35, dist: 1, target: [0, 0, 0], pan: [0, 0], zoom: 1, extent: 1 },
  };
  window.corpuscleViewer = S;
  const canvas = $('view');
  const gl = canvas.getContext('webgl2', { antialias: true, preserveDrawingBuffer: true });
  if (!gl) { $('status').textContent = 'WebGL2 is not available in this browser'; S.errors.push('no webgl2'); return; }

  // ---- shaders ----------------------------------------------------------------------------
  const RAMP = `vec3 ramp(float t){ t=clamp(t,0.0,1.0);
    const vec3 c0=vec3(0.2777,0.0054,0.3341), c1=vec3(0.1051,1.4046,1.3846), c2=vec3(-0.3309,0.2148,0.0951),
      c3=vec3(-4.6342,-5.7991,-19.3324), c4=vec3(6.2283,14.1799,56.6906), c5=vec3(4.7764,-13.7451,-65.3530),
      c6=vec3(-5.4355,4.6459,26.3124);
    return c0+t*(c1+t*(c2+t*(c3+t*(c4+t*(c5+t*c6))))); }`;
  const PVS = `#version 300 es
    in vec3 aPos; in float aCol;
    uniform vec3 uLo, uSpan; uniform mat4 uView, uProj; uniform float uRadius, uScale, uPersp; uniform int uDim;
    out float vCol;
    void main(){ vec3 p = uLo + aPos*uSpan; if (uDim == 2) p.z = 0.0;
      vec4 v = uView*vec4(p, 1.0); gl_Position = uProj*v;
      gl_PointSize = clamp(uRadius*uScale/mix(1.0, max(-v.z, 1e-4), uPersp), 1.5, 64.0); vCol = aCol; }`;
  const PFS = `#version 300 es
    precision highp float; in float vCol; uniform int uHasCol; out vec4 color; ${RAMP}
    void main(){ vec2 c = gl_PointCoord*2.0-1.0; float r2 = dot(c,c); if (r2 > 1.0) discard;
      vec3 n = vec3(c.x, -c.y, sqrt(1.0-r2)); vec3 L = normalize(vec3(0.45,0.6,0.75));
      float d = max(dot(n,L),0.0); float s = pow(max(dot(reflect(-L,n), vec3(0,0,1)),0.0), 24.0);
      vec3 base = uHasCol == 1 ? ramp(vCol) : vec3(0.30,0.58,0.92);
      color = vec4(base*(0.30+0.70*d) + 0.25*s, 1.0);
      gl_FragDepth = gl_FragCoord.z - 0.0005*n.z; }`;
  const LVS = `#version 300 es
    in vec3 aPos; uniform mat4 uView, uProj; uniform float uPointSize;
    void main(){ gl_Position = uProj*uView*vec4(aPos,1.0); gl_PointSize = uPointSize; }`;
  const LFS = `#version 300 es
    precision highp float; uniform vec4 uColor; uniform int uRound; out vec4 color;
    void main(){ if (uRound == 1) { vec2 c = gl_PointCoord*2.0-1.0; if (dot(c,c) > 1.0) discard; } color = uColor; }`;
  function program(vs, fs) {
    const p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
      const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
      gl.attachShader(p, s);
    }
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    const u = {}; const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < n; i++) { const name = gl.getActiveUniform(p, i).name; u[name] = gl.getUniformLocation(p, name); }
    return { p, u, aPos: gl.getAttribLocation(p, 'aPos'), aCol: gl.getAttribLocation(p, 'aCol') };
  }
  const P = program(PVS, PFS), L = program(LVS, LFS);
  const pointVao = gl.createVertexArray(), posBuf = gl.createBuffer(), colBuf = gl.createBuffer();
  gl.bindVertexArray(pointVao);
  gl.bindBuffer(gl.ARRAY_BUFFER, posBuf); gl.enableVertexAttribArray(P.aPos);
  gl.vertexAttribPointer(P.aPos, 3, gl.UNSIGNED_SHORT, true, 0, 0);
  gl.bindVertexArray(null);
  const lineVao = gl.createVertexArray(), lineBuf = gl.createBuffer();
  gl.bindVertexArray(lineVao); gl.bindBuffer(gl.ARRAY_BUFFER, lineBuf);
  gl.enableVertexAttribArray(L.aPos); gl.vertexAttribPointer(L.aPos, 3, gl.FLOAT, false, 0, 0);
  gl.bindVertexArray(null);

  // ---- matrices ----------------------------------------------------------------------------
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };
  function lookAt(eye, at, up) {
    const z = norm(sub(eye, at)), x = norm(cross(up, z)), y = cross(z, x);
    return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
      -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
  }
  function perspective(fovy, aspect, near, far) {
    const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
  }
  function ortho(l, r, b, t, n, f) {
    return new Float32Array([2 / (r - l), 0, 0, 0, 0, 2 / (t - b), 0, 0, 0, 0, -2 / (f - n), 0,
      -(r + l) / (r - l), -(t + b) / (t - b), -(f + n) / (f - n), 1]);
  }
  function rotate(q, v) {  // q = [w, x, y, z]
    const [w, x, y, z] = q, u = [x, y, z], t = cross(u, v).map((c) => 2 * c), c2 = cross(u, t);
    return [v[0] + w * t[0] + c2[0], v[1] + w * t[1] + c2[1], v[2] + w * t[2] + c2[2]];
  }

  // ---- scene geometry from the header -------------------------------------------------------
  function upAxis(h) {
    const g = h.gravity || [0, 0, -9.81];
    let k = 0; for (let i = 1; i < g.length; i++) if (Math.abs(g[i]) > Math.abs(g[k])) k = i;
    if (!g[k]) k = 2;
    return { k, sign: g[k] > 0 ? -1 : 1 };
  }
  function containerLines(h) {
    const c = h.container, out = [];
    if (!c) return out;
    const seg = (a, b) => out.push(...a, ...b);
    if (c.type === 'sphere') {
      const C = [...c.center, 0, 0, 0].slice(0, 3), r = c.radius, N = 96;
      const circle = (f) => { for (let i = 0; i < N; i++) seg(f(i / N * 2 * Math.PI), f((i + 1) / N * 2 * Math.PI)); };
      if (S.dim === 2) { circle((t) => [C[0] + r * Math.cos(t), C[1] + r * Math.sin(t), 0]); return out; }
      for (const lat of [-60, -30, 0, 30, 60]) {
        const z = r * Math.sin(lat * Math.PI / 180), rr = r * Math.cos(lat * Math.PI / 180);
        circle((t) => [C[0] + rr * Math.cos(t), C[1] + rr * Math.sin(t), C[2] + z]);
      }
      for (let m = 0; m < 4; m++) {
        const a = m * Math.PI / 4;
        circle((t) => [C[0] + r * Math.cos(t) * Math.cos(a), C[1] + r * Math.cos(t) * Math.sin(a), C[2] + r * Math.sin(t)]);
      }
    } else if (c.type === 'box') {
      const lo = [...c.min, 0].slice(0, 3), hi = [...c.max, 0].slice(0, 3);
      boxEdges(lo, hi, (p) => p).forEach((p) => out.push(...p));
    }
    return out;
  }
  function boxEdges(lo, hi, tf) {
    const pts = [];
    for (let a = 0; a < 3; a++) for (let i = 0; i < 2; i++) for (let j = 0; j < 2; j++) {
      const b = (a + 1) % 3, c = (a + 2) % 3, p = [0, 0, 0], q = [0, 0, 0];
      p[a] = lo[a]; q[a] = hi[a]; p[b] = q[b] = i ? hi[b] : lo[b]; p[c] = q[c] = j ? hi[c] : lo[c];
      pts.push(tf(p), tf(q));
    }
    return pts;
  }
  const PIPS = { 1: [[0, 0]], 2: [[-1, -1], [1, 1]], 3: [[-1, -1], [0, 0], [1, 1]], 4: [[-1, -1], [-1, 1], [1, -1], [1, 1]],
    5: [[-1, -1], [-1, 1], [1, -1], [1, 1], [0, 0]], 6: [[-1, -1], [-1, 0], [-1, 1], [1, -1], [1, 0], [1, 1]] };
  function bodyGeometry(body, pose) {  // {edges, faces: [{tris, normal}], pips}
    const h = body.half_extents || [0.01, 0.01, 0.01], pos = pose.position, q = pose.orientation;
    const tf = (p) => { const r = rotate(q, p); return [r[0] + pos[0], r[1] + pos[1], r[2] + pos[2]]; };
    const lo = h.map((x) => -x);
    const edges = boxEdges(lo, h, tf).flat();
    const faces = [], pips = [];
    const faceMap = body.faces || {};
    for (let a = 0; a < 3; a++) for (const s of [-1, 1]) {
      const n = [0, 0, 0]; n[a] = s; const b = (a + 1) % 3, c = (a + 2) % 3;
      const corner = (i, j) => { const p = [0, 0, 0]; p[a] = s * h[a]; p[b] = i * h[b]; p[c] = j * h[c]; return tf(p); };
      faces.push({ tris: [corner(-1, -1), corner(1, -1), corner(1, 1), corner(-1, -1), corner(1, 1), corner(-1, 1)].flat(),
        normal: rotate(q, n) });
      const label = Object.keys(faceMap).find((k) => { const m = faceMap[k]; return Math.abs(m[0] - n[0]) + Math.abs(m[1] - n[1]) + Math.abs(m[2] - n[2]) < 1e-3; });
      for (const [u, v] of (PIPS[label] || [])) {
        const p = [0, 0, 0]; p[a] = s * h[a] * 1.03; p[b] = u * 0.5 * h[b]; p[c] = v * 0.5 * h[c];
        pips.push(...tf(p));
      }
    }
    return { edges, faces, pips };
  }
  function answerOf(body, pose, window_) {
    if (!body.faces || !pose) return null;
    let best = null, bd = -2;
    for (const [k, n] of Object.entries(body.faces)) {
      const d = dot(rotate(pose.orientation, n), window_ || [0, 0, 1]);
      if (d > bd) { bd = d; best = k; }
    }
    return best === null ? null : { face: +best, answer: (body.answers || [])[+best - 1] || '' };
  }

  // ---- camera ------------------------------------------------------------------------------
  function setupCamera(h) {
    const c = h.container; let centre = [0, 0, 0], extent = 1;
    if (c && c.type === 'sphere') { centre = [...c.center, 0, 0].slice(0, 3); extent = c.radius; }
    else if (c && c.type === 'box') {
      centre = [0, 1, 2].map((i) => ((c.min[i] || 0) + (c.max[i] || 0)) / 2);
      extent = Math.max(...c.max.map((x, i) => (x - c.min[i]) / 2));
    }
    Object.assign(S.cam, { target: centre, extent, dist: extent * 3.4, pan: [centre[0], centre[1]], zoom: 1 });
  }
  function matrices() {
    const w = canvas.width, hgt = canvas.height, aspect = w / Math.max(1, hgt), cam = S.cam;
    if (S.dim === 2) {
      const half = cam.extent * 1.15 / cam.zoom;
      const hx = aspect >= 1 ? half * aspect : half, hy = aspect >= 1 ? half : half / aspect;
      return { view: lookAt([cam.pan[0], cam.pan[1], 1], [cam.pan[0], cam.pan[1], 0], [0, 1, 0]),
        proj: ortho(-hx, hx, -hy, hy, 0.01, 10), scale: hgt / (2 * hy), persp: 0 };
    }
    const up = upAxis(S.header), k = up.k, e1 = (k + 1) % 3, e2 = (k + 2) % 3;
    const eye = cam.target.slice(), upv = [0, 0, 0]; upv[k] = up.sign;
    eye[e1] += cam.dist * Math.cos(cam.el) * Math.cos(cam.az);
    eye[e2] += cam.dist * Math.cos(cam.el) * Math.sin(cam.az);
    eye[k] += up.sign * cam.dist * Math.sin(cam.el);
    const fovy = 0.7;
    return { view: lookAt(eye, cam.target, upv), proj: perspective(fovy, aspect, cam.dist * 0.05, cam.dist * 10),
      scale: hgt / (2 * Math.tan(fovy / 2)), persp: 1 };
  }

  // ---- drawing -----------------------------------------------------------------------------
  let staticLines = new Float32Array(0), nPoints = 0, hasColor = false, dirty = true;
  function drawLines(data, mode, color, size, round) {
    if (!data.length) return;
    gl.bindVertexArray(lineVao); gl.bindBuffer(gl.ARRAY_BUFFER, lineBuf);
    gl.bufferData(gl.ARRAY_BUFFER, data instanceof Float32Array ? data : new Float32Array(data), gl.STREAM_DRAW);
    gl.uniform4fv(L.u.uColor, color); gl.uniform1f(L.u.uPointSize, size || 1); gl.uniform1i(L.u.uRound, round ? 1 : 0);
    gl.drawArrays(mode, 0, data.length / 3);
  }
  function draw() {
    dirty = false;
    const dpr = window.devicePixelRatio || 1, w = Math.round(canvas.clientWidth * dpr), h = Math.round(canvas.clientHeight * dpr);
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(0.078, 0.086, 0.11, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (!S.header) return;
    gl.enable(gl.DEPTH_TEST);
    const M = matrices(), f = S.frame;
    if (f && nPoints) {
      gl.useProgram(P.p); gl.bindVertexArray(pointVao);
      const lo = [...f.meta.lo, 0, 0].slice(0, 3), hi = [...f.meta.hi, 0, 0].slice(0, 3);
      gl.uniform3fv(P.u.uLo, lo); gl.uniform3fv(P.u.uSpan, hi.map((x, i) => x - lo[i]));
      gl.uniformMatrix4fv(P.u.uView, false, M.view); gl.uniformMatrix4fv(P.u.uProj, false, M.proj);
      gl.uniform1f(P.u.uRadius, S.header.particle_radius || S.cam.extent / 80);
      gl.uniform1f(P.u.uScale, M.scale); gl.uniform1f(P.u.uPersp, M.persp);
      gl.uniform1i(P.u.uDim, S.dim); gl.uniform1i(P.u.uHasCol, hasColor ? 1 : 0);
      if (!hasColor) gl.disableVertexAttribArray(P.aCol);
      gl.drawArrays(gl.POINTS, 0, nPoints);
    }
    gl.useProgram(L.p);
    gl.uniformMatrix4fv(L.u.uView, false, M.view); gl.uniformMatrix4fv(L.u.uProj, false, M.proj);
    drawLines(staticLines, gl.LINES, [0.55, 0.6, 0.7, 1]);
    for (const body of (S.header.bodies || [])) {
      const pose = f && f.meta.rigid && f.meta.rigid[body.name];
      if (!pose || body.shape !== 'box') continue;
      const g = bodyGeometry(body, pose);
      for (const face of g.faces) {
        const shade = 0.55 + 0.45 * Math.max(0, dot(norm(face.normal), norm([0.4, 0.5, 0.8])));
        drawLines(face.tris, gl.TRIANGLES, [0.96 * shade, 0.94 * shade, 0.88 * shade, 1]);
      }
      drawLines(g.edges, gl.LINES, [0.1, 0.1, 0.12, 1]);
      const pipPx = Math.max(2, (body.half_extents[0] * 0.35) * M.scale / (M.persp ? S.cam.dist : 1));
      drawLines(g.pips, gl.POINTS, [0.08, 0.08, 0.1, 1], pipPx, true);
    }
  }
  function frameLoop() { if (dirty) draw(); requestAnimationFrame(frameLoop); }

  // ---- the connection ----------------------------------------------------------------------
  const token = new URLSearchParams(location.search).get('token');
  const wsUrl = (location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws' + (token ? '?token=' + encodeURIComponent(token) : '');
  let ws = null;
  function send(msg) { if (ws && ws.readyState === 1) ws.send(JSON.stringify(msg)); }
  function onHello(h) {
    S.hello = h; S.mode = h.mode; S.header = h.header || {}; S.dim = S.header.dim || 3; S.nFrames = h.frames || 0;
    S.paused = !!h.paused;
    setupCamera(S.header);
    staticLines = new Float32Array(containerLines(S.header));
    $('title').textContent = `${S.header.scene || 'run'} (${S.header.kind || '?'}, ${S.dim}-D) · ${h.mode === 'live' ? 'live' : 'recorded'}`;
    const sel = $('color-by');
    for (const name of h.fields || []) { const o = document.createElement('option'); o.value = o.textContent = name; sel.appendChild(o); }
    sel.value = (h.fields || []).includes('density') ? 'density' : ((h.fields || [])[0] || '');
    const ctl = h.controls || {};
    if (h.mode === 'live') {
      $('live-controls').hidden = false;
      S.control = {}; for (const [k, n] of Object.entries(ctl)) S.control[k] = new Array(n).fill(0);
      $('control-line').hidden = !Object.keys(ctl).length;
      showControl();
    } else {
      $('playback').hidden = false; $('rate-line').hidden = true;
      $('scrub').max = Math.max(0, S.nFrames - 1);
    }
    $('status').textContent = h.mode === 'live' ? (S.paused ? 'paused' : 'running') : `${S.nFrames} frames`;
    S.ready = true; dirty = true;
  }
  function onFrame(buf) {
    const dv = new DataView(buf);
    const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
    if (magic !== 'CPSL') { S.errors.push('bad frame magic'); return; }
    const index = dv.getUint32(12, true), step = Number(dv.getBigInt64(16, true)), time = dv.getFloat64(24, true);
    const n = dv.getUint32(32, true), dim = dv.getUint32(36, true), jlen = dv.getUint32(40, true), cb = dv.getUint32(44, true);
    let off = 48;
    const meta = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, off, jlen)));
    off += jlen;
    let q = new Uint16Array(buf, off, n * dim);
    off += n * dim * 2; off += (4 - (off % 4)) % 4;
    if (dim === 2) {  // pad to 3 components (z = 0)
      const q3 = new Uint16Array(n * 3); for (let i = 0; i < n; i++) { q3[3 * i] = q[2 * i]; q3[3 * i + 1] = q[2 * i + 1]; }
      q = q3;
    }
    gl.bindVertexArray(pointVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, posBuf); gl.bufferData(gl.ARRAY_BUFFER, q, gl.DYNAMIC_DRAW);
    hasColor = cb === 1 && !!meta.color;
    if (hasColor) {
      gl.bindBuffer(gl.ARRAY_BUFFER, colBuf); gl.bufferData(gl.ARRAY_BUFFER, new Uint8Array(buf, off, n), gl.DYNAMIC_DRAW);
      gl.enableVertexAttribArray(P.aCol); gl.vertexAttribPointer(P.aCol, 1, gl.UNSIGNED_BYTE, true, 0, 0);
    } else if (P.aCol >= 0) { gl.disableVertexAttribArray(P.aCol); gl.vertexAttrib1f(P.aCol, 0.5); }
    gl.bindVertexArray(null);
    nPoints = n;
    S.frame = { index, step, time, n, dim, meta };
    S.framesReceived++; S.lastIndex = index; S.lastStep = step; S.pending = false;
    if (meta.paused !== undefined) S.paused = !!meta.paused;
    updateOverlay(); dirty = true;
  }
  function fmt(x, d) { return x === null || x === undefined || !isFinite(x) ? '–' : (+x).toFixed(d); }
  function updateOverlay() {
    const f = S.frame, m = f.meta;
    $('sim-time').textContent = fmt(f.time, 4); $('sim-step').textContent = f.step.toLocaleString('en');
    $('frame-index').textContent = S.mode === 'view' ? `${f.index + 1}/${S.nFrames}` : String(f.index);
    $('frame-counter').textContent = String(S.framesReceived);
    $('steps-rate').textContent = m.steps_per_second ? Math.round(m.steps_per_second).toLocaleString('en') : '–';
    $('particle-count').textContent = f.n.toLocaleString('en');
    const body = (S.header.bodies || []).find((b) => b.faces);
    let ans = m.result && m.result.answer ? { face: m.result.answer_face, answer: m.result.answer } : null;
    if (!ans && body) ans = answerOf(body, m.rigid && m.rigid[body.name], S.header.window);
    if (ans) { $('answer-line').hidden = false; $('answer').textContent = `${ans.answer} (face ${ans.face})`; }
    if (S.mode === 'view') { $('scrub').value = f.index; }
    else $('status').textContent = S.paused ? 'paused' : 'running';
    const c = m.color;
    $('colorbar-box').hidden = !c;
    if (c) {
      $('bar-lo').textContent = c.range[0].toPrecision(4); $('bar-hi').textContent = c.range[1].toPrecision(4);
      $('bar-name').textContent = c.field + (c.unit ? ` (${c.unit})` : '');
    }
  }
  function connect() {
    ws = new WebSocket(wsUrl); ws.binaryType = 'arraybuffer';
    ws.onmessage = (ev) => {
      try {
        if (typeof ev.data === 'string') { const m = JSON.parse(ev.data); if (m.type === 'hello') onHello(m); }
        else onFrame(ev.data);
      } catch (e) { S.errors.push(String(e)); console.error(e); }
    };
    ws.onclose = () => { $('status').textContent = 'disconnected (the run or the server ended)'; S.closed = true; };
  }

  // ---- colour bar --------------------------------------------------------------------------
  (function paintBar() {
    const c = $('colorbar'), g = c.getContext('2d'), C = [[0.2777, 0.0054, 0.3341], [0.1051, 1.4046, 1.3846], [-0.3309, 0.2148, 0.0951],
      [-4.6342, -5.7991, -19.3324], [6.2283, 14.1799, 56.6906], [4.7764, -13.7451, -65.3530], [-5.4355, 4.6459, 26.3124]];
    for (let x = 0; x < c.width; x++) {
      const t = x / (c.width - 1), rgb = [0, 1, 2].map((k) => { let v = 0; for (let i = 6; i >= 0; i--) v = v * t + C[i][k]; return Math.round(255 * Math.min(1, Math.max(0, v))); });
      g.fillStyle = `rgb(${rgb.join(',')})`; g.fillRect(x, 0, 1, c.height);
    }
  })();

  // ---- input -------------------------------------------------------------------------------
  $('color-by').addEventListener('change', (e) => send({ type: 'color', field: e.target.value || null }));
  $('pause').addEventListener('click', () => togglePause());
  function togglePause() {
    S.paused = !S.paused; send({ type: S.paused ? 'pause' : 'resume' });
    $('pause').textContent = S.paused ? 'resume' : 'pause'; $('status').textContent = S.paused ? 'paused' : 'running';
  }
  function showControl() {
    const c = S.control || {};
    $('control').textContent = Object.entries(c).map(([k, v]) => `${k === 'acceleration' ? 'a' : k === 'torque' ? 'τ' : k}=(${v.map((x) => x.toFixed(3)).join(', ')})`).join(' ');
  }
  const KEYS = { w: ['acceleration', 1, 1], s: ['acceleration', 1, -1], a: ['acceleration', 0, -1], d: ['acceleration', 0, 1],
    e: ['acceleration', 2, 1], q: ['acceleration', 2, -1], i: ['torque', 0, 1], k: ['torque', 0, -1],
    l: ['torque', 1, 1], j: ['torque', 1, -1], o: ['torque', 2, 1], u: ['torque', 2, -1] };
  const STEP = { acceleration: 2.0, torque: 0.005 };
  window.addEventListener('keydown', (e) => {
    if (S.mode !== 'live' || !S.control || e.target.tagName === 'SELECT' || e.target.tagName === 'INPUT') return;
    const key = e.key.toLowerCase();
    if (key === 'p') { togglePause(); return; }
    if (key === ' ') { for (const k of Object.keys(S.control)) S.control[k].fill(0); }
    else if (KEYS[key] && S.control[KEYS[key][0]]) {
      const [name, axis, sign] = KEYS[key], v = S.control[name], lim = (S.hello.limits || {})[name] || 100;
      v[axis] += sign * (STEP[name] || 1);
      const l = Math.hypot(...v); if (l > lim) for (let i = 0; i < v.length; i++) v[i] *= lim / l * 0.999;
    } else return;
    e.preventDefault();
    send(Object.assign({ type: 'control' }, S.control)); showControl();
  });
  let drag = null;
  canvas.addEventListener('pointerdown', (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener('pointerup', () => { drag = null; });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const dx = e.clientX - drag[0], dy = e.clientY - drag[1]; drag = [e.clientX, e.clientY];
    if (S.dim === 2) {
      const s = 2 * S.cam.extent * 1.15 / S.cam.zoom / canvas.clientHeight;
      S.cam.pan[0] -= dx * s; S.cam.pan[1] += dy * s;
    } else {
      S.cam.az -= dx * 0.008; S.cam.el = Math.max(-1.5, Math.min(1.5, S.cam.el + dy * 0.008));
    }
    dirty = true;
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault(); const f = Math.exp(e.deltaY * 0.001);
    if (S.dim === 2) S.cam.zoom /= f; else S.cam.dist *= f;
    dirty = true;
  }, { passive: false });
  window.addEventListener('resize', () => { dirty = true; });

  // ---- playback (recorded runs) ---------------------------------------------------------------
  function seek(i) { S.pending = true; send({ type: 'seek', frame: Math.max(0, Math.min(S.nFrames - 1, i | 0)) }); }
  S.seek = seek;
  $('scrub').addEventListener('input', (e) => { S.playing = false; $('play').textContent = 'play'; seek(+e.target.value); });
  $('play').addEventListener('click', () => {
    S.playing = !S.playing; $('play').textContent = S.playing ? 'pause' : 'play';
    if (S.playing && S.frame && S.frame.index >= S.nFrames - 1) seek(0);
  });
  $('speed').addEventListener('change', (e) => { S.speed = +e.target.value; });
  let lastTick = 0;
  setInterval(() => {
    if (S.mode !== 'view' || !S.playing || S.pending || !S.frame) return;
    const now = performance.now(); if (now - lastTick < 1000 / (20 * S.speed)) return;
    lastTick = now;
    if (S.frame.index >= S.nFrames - 1) { S.playing = false; $('play').textContent = 'play'; return; }
    seek(S.frame.index + 1);
  }, 10);

  connect();
  requestAnimationFrame(frameLoop);
})();
