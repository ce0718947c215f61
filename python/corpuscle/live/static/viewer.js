// corpuscle live viewer: WebGL2, no dependencies. Wire format: corpuscle/live/protocol.py.
// Everything drawn comes from the run header (dimension, container, obstacles, rigid bodies,
// units) and the frames (positions, a colour field, rigid poses, diagnostics, the result):
// a new scene kind needs no change here.
'use strict';
(function () {
  const $ = (id) => document.getElementById(id);
  const S = {  // the page's state (tests read window.corpuscleViewer)
    ready: false, mode: null, hello: null, header: null, scene: null, dim: 3, framesReceived: 0, frame: null,
    lastIndex: -1, lastStep: -1, errors: [], warnings: [], control: null, paused: false, sent: 0,
    playing: false, pending: false, speed: 1, nFrames: 0, drawn: 0, drawRate: 0, receiveRate: 0,
    obstaclesDrawn: 0, bodiesDrawn: 0, shakeDrag: false, dragging: null,
    cam: { az: 0.6, el: 0.35, dist: 1, target: [0, 0, 0], pan: [0, 0], zoom: 1, extent: 1, half: [1, 1] },
  };
  window.corpuscleViewer = S;
  const canvas = $('view');
  // no multisampling: it multiplies the fragments a million point sprites cost (4x on a
  // software rasteriser); the drawing buffer is kept for screenshots (tests, docs)
  const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true });
  if (!gl) { $('status').textContent = 'WebGL2 is not available in this browser'; S.errors.push('no webgl2'); return; }
  const dbg = gl.getExtension('WEBGL_debug_renderer_info');
  S.renderer = dbg ? gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);

  // ---- shaders ----------------------------------------------------------------------------
  const RAMP = `vec3 ramp(float t){ t=clamp(t,0.0,1.0);
    const vec3 c0=vec3(0.2777,0.0054,0.3341), c1=vec3(0.1051,1.4046,1.3846), c2=vec3(-0.3309,0.2148,0.0951),
      c3=vec3(-4.6342,-5.7991,-19.3324), c4=vec3(6.2283,14.1799,56.6906), c5=vec3(4.7764,-13.7451,-65.3530),
      c6=vec3(-5.4355,4.6459,26.3124);
    return c0+t*(c1+t*(c2+t*(c3+t*(c4+t*(c5+t*c6))))); }`;
  // positions come as normalised uint16 (x = lo + q (hi - lo)); a 2-D frame's z is 0. Each
  // particle is a point sprite at its centre's depth, shaded as a lit sphere (no per-fragment
  // depth: writing gl_FragDepth turns off the early depth test). Instanced quads were tried:
  // a software rasteriser (SwiftShader) draws them ten times slower than points
  const PVS = `#version 300 es
    in vec3 aPos; in float aCol;
    uniform vec3 uLo, uSpan; uniform mat4 uView, uProj; uniform float uRadius, uScale, uPersp; uniform int uDim;
    out float vCol;
    void main(){ vec3 p = uLo + aPos*uSpan; if (uDim == 2) p.z = 0.0;
      vec4 v = uView*vec4(p, 1.0); gl_Position = uProj*v;
      gl_PointSize = clamp(2.0*uRadius*uScale/mix(1.0, max(-v.z, 1e-4), uPersp), 1.5, 256.0); vCol = aCol; }`;
  const PFS = `#version 300 es
    precision mediump float; in float vCol; uniform int uHasCol; out vec4 color; ${RAMP}
    void main(){ vec2 c = gl_PointCoord*2.0-1.0; float r2 = dot(c,c); if (r2 > 1.0) discard;
      vec3 n = vec3(c.x, -c.y, sqrt(1.0-r2)); const vec3 L = vec3(0.4319, 0.5759, 0.7199);
      float d = max(dot(n,L),0.0); float s = pow(max(dot(reflect(-L,n), vec3(0,0,1)),0.0), 24.0);
      vec3 base = uHasCol == 1 ? ramp(vCol) : vec3(0.30,0.58,0.92);
      color = vec4(base*(0.30+0.70*d) + 0.25*s, 1.0); }`;
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
  const lineVao = gl.createVertexArray(), lineBuf = gl.createBuffer();
  gl.bindVertexArray(lineVao); gl.bindBuffer(gl.ARRAY_BUFFER, lineBuf);
  gl.enableVertexAttribArray(L.aPos); gl.vertexAttribPointer(L.aPos, 3, gl.FLOAT, false, 0, 0);
  gl.bindVertexArray(null);

  // ---- vectors and matrices -----------------------------------------------------------------
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };
  const pad3 = (p) => [+(p[0] || 0), +(p[1] || 0), +(p[2] || 0)];
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
  function mulVec(m, v) {  // column-major 4x4 times (x, y, z, 1)
    const o = [0, 0, 0, 0];
    for (let r = 0; r < 4; r++) o[r] = m[r] * v[0] + m[4 + r] * v[1] + m[8 + r] * v[2] + m[12 + r];
    return o;
  }
  function rotate(q, v) {  // q = [w, x, y, z]
    const [w, x, y, z] = q, u = [x, y, z], t = cross(u, v).map((c) => 2 * c), c2 = cross(u, t);
    return [v[0] + w * t[0] + c2[0], v[1] + w * t[1] + c2[1], v[2] + w * t[2] + c2[2]];
  }

  // ---- scene geometry from the header -------------------------------------------------------
  function upAxis() {
    const sc = S.scene || {}, up = sc.up || S.header.up;
    if (typeof up === 'string' && /^[+-]?[xyz]$/.test(up)) {
      return { k: 'xyz'.indexOf(up.slice(-1)), sign: up[0] === '-' ? -1 : 1 };
    }
    const g = sc.gravity || S.header.gravity || [0, 0, -9.81];
    let k = 0; for (let i = 1; i < g.length; i++) if (Math.abs(g[i]) > Math.abs(g[k])) k = i;
    if (!g[k]) return { k: 2, sign: 1 };
    return { k, sign: g[k] > 0 ? -1 : 1 };
  }
  function circle(out, f, N) { for (let i = 0; i < N; i++) out.push(...f(i / N * 2 * Math.PI), ...f((i + 1) / N * 2 * Math.PI)); }
  function sphereLines(out, C, r) {
    if (S.dim === 2) { circle(out, (t) => [C[0] + r * Math.cos(t), C[1] + r * Math.sin(t), 0], 96); return; }
    for (const lat of [-60, -30, 0, 30, 60]) {
      const z = r * Math.sin(lat * Math.PI / 180), rr = r * Math.cos(lat * Math.PI / 180);
      circle(out, (t) => [C[0] + rr * Math.cos(t), C[1] + rr * Math.sin(t), C[2] + z], 96);
    }
    for (let m = 0; m < 4; m++) {
      const a = m * Math.PI / 4;
      circle(out, (t) => [C[0] + r * Math.cos(t) * Math.cos(a), C[1] + r * Math.cos(t) * Math.sin(a), C[2] + r * Math.sin(t)], 96);
    }
  }
  function boxEdges(lo, hi, tf) {
    const pts = [];
    for (let a = 0; a < 3; a++) for (let i = 0; i < 2; i++) for (let j = 0; j < 2; j++) {
      const b = (a + 1) % 3, c = (a + 2) % 3, p = [0, 0, 0], q = [0, 0, 0];
      p[a] = lo[a]; q[a] = hi[a]; p[b] = q[b] = i ? hi[b] : lo[b]; p[c] = q[c] = j ? hi[c] : lo[c];
      if (p[0] === q[0] && p[1] === q[1] && p[2] === q[2]) continue;  // a flat (2-D) box's zero-length edges
      pts.push(tf(p), tf(q));
    }
    return pts;
  }
  function containerLines() {
    const c = (S.scene || {}).container, out = [];
    if (!c) return out;
    if (c.type === 'sphere') sphereLines(out, pad3(c.center || [0, 0, 0]), c.radius);
    else if (c.type === 'box') boxEdges(pad3(c.min), pad3(c.max), (p) => p).forEach((p) => out.push(...p));
    else S.warnings.push(`container type ${c.type} is not drawn`);
    return out;
  }
  // a simple polygon (2-D points, either orientation) as triangles: ear clipping
  function triangulate(pts) {
    const n = pts.length, idx = [...Array(n).keys()], tris = [];
    if (n < 3) return tris;
    let area = 0; for (let i = 0; i < n; i++) { const a = pts[i], b = pts[(i + 1) % n]; area += a[0] * b[1] - b[0] * a[1]; }
    const s = area >= 0 ? 1 : -1;
    const cr = (a, b, c) => s * ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]));
    const inside = (p, a, b, c) => cr(a, b, p) >= 0 && cr(b, c, p) >= 0 && cr(c, a, p) >= 0;
    let guard = 0;
    while (idx.length > 3 && guard++ < 4 * n * n) {
      let cut = false;
      for (let k = 0; k < idx.length; k++) {
        const i0 = idx[(k + idx.length - 1) % idx.length], i1 = idx[k], i2 = idx[(k + 1) % idx.length];
        const a = pts[i0], b = pts[i1], c = pts[i2];
        if (cr(a, b, c) <= 0) continue;
        let ear = true;
        for (const j of idx) { if (j !== i0 && j !== i1 && j !== i2 && inside(pts[j], a, b, c)) { ear = false; break; } }
        if (!ear) continue;
        tris.push(a, b, c); idx.splice(k, 1); cut = true; break;
      }
      if (!cut) break;  // degenerate: what is left stays unfilled (its outline is drawn)
    }
    if (idx.length === 3) tris.push(pts[idx[0]], pts[idx[1]], pts[idx[2]]);
    return tris;
  }
  // obstacles, prepared once: outlines, fills (2-D polygons), and how a diagnostic turns them
  function prepareObstacles() {
    const out = [];
    for (const ob of ((S.scene || {}).obstacles || [])) {
      const o = { name: ob.name || '', type: ob.type, lines: [], fill: [], turn: null };
      if (ob.turn && typeof ob.turn === 'object' && Array.isArray(ob.turn.about)) {
        o.turn = { diagnostic: String(ob.turn.diagnostic || ''), about: pad3(ob.turn.about), sign: +(ob.turn.sign ?? 1) };
      }
      // a moving body (the SPH box kinds; 2-D or 3-D): its points at t = 0 about `origin`, turned by `rotation`
      if (ob.pose && typeof ob.pose === 'object' && Array.isArray(ob.pose.origin) &&
          (ob.pose.origin.length === 2 || ob.pose.origin.length === 3) &&
          Array.isArray(ob.pose.rotation) && ob.pose.rotation.length === ob.pose.origin.length) {
        o.pose = { diagnostic: String(ob.pose.diagnostic || ''), origin: ob.pose.origin.map(Number), R0: ob.pose.rotation.map((r) => r.map(Number)) };
      }
      if (Array.isArray(ob.points) && ob.points.length >= 2 && Array.isArray(ob.extrude) && ob.extrude.length === 2 && S.dim === 3) {
        // an x-y section swept along z (the 3-D wind tunnel's airfoil): its outline at both ends,
        // joined at the section's two extreme vertices in x (leading and trailing edge)
        const [z0, z1] = ob.extrude.map(Number), n = ob.points.length;
        let a = 0, b = 0;
        ob.points.forEach((p, i) => { if (p[0] < ob.points[a][0]) a = i; if (p[0] > ob.points[b][0]) b = i; });
        for (const z of [z0, z1]) for (let i = 0; i < n; i++) {
          const p = ob.points[i], q = ob.points[(i + 1) % n];
          o.lines.push(p[0], p[1], z, q[0], q[1], z);
        }
        for (const i of [a, b]) o.lines.push(ob.points[i][0], ob.points[i][1], z0, ob.points[i][0], ob.points[i][1], z1);
      } else if (Array.isArray(ob.points) && ob.points.length >= 2) {
        const pts = ob.points.map(pad3), n = pts.length;
        for (let i = 0; i < n; i++) o.lines.push(...pts[i], ...pts[(i + 1) % n]);
        if (ob.points[0].length === 2 || S.dim === 2) triangulate(pts).forEach((p) => o.fill.push(p[0], p[1], 0));
      } else if (ob.type === 'mesh' && Array.isArray(ob.vertices) && Array.isArray(ob.faces)) {
        // a triangle mesh (a body of the SPH box kinds): each edge once
        const seen = new Set(), V = ob.vertices.map(pad3);
        for (const f of ob.faces) for (let e = 0; e < 3; e++) {
          const a = f[e], b = f[(e + 1) % 3], key = a < b ? `${a},${b}` : `${b},${a}`;
          if (seen.has(key) || !V[a] || !V[b]) continue;
          seen.add(key);
          o.lines.push(...V[a], ...V[b]);
        }
      } else if (ob.type === 'box' && ob.min && ob.max) {
        boxEdges(pad3(ob.min), pad3(ob.max), (p) => p).forEach((p) => o.lines.push(...p));
      } else if ((ob.type === 'sphere' || ob.type === 'circle') && ob.radius > 0) {
        const C = pad3(ob.center || [0, 0, 0]);
        sphereLines(o.lines, C, ob.radius);
        if (S.dim === 2) circle(o.fill, (t) => [C[0] + ob.radius * Math.cos(t), C[1] + ob.radius * Math.sin(t), 0], 64);
        if (S.dim === 2) { const f = []; for (let i = 0; i < o.fill.length; i += 6) f.push(...C, o.fill[i], o.fill[i + 1], 0, o.fill[i + 3], o.fill[i + 4], 0); o.fill = f; }
      } else { S.warnings.push(`obstacle ${o.name || o.type} (${ob.type}) is not drawn`); continue; }
      o.lines = new Float32Array(o.lines); o.fill = new Float32Array(o.fill);
      out.push(o);
    }
    return out;
  }
  // an obstacle's vertices as the frame's diagnostic turns it (counter-clockwise degrees about z)
  function turned(o, data) {
    if (o.pose && data.length) {  // at the frame's pose: c + R R0^T (p - c0)
      const D = S.frame && S.frame.meta.diagnostics ? S.frame.meta.diagnostics : {}, n = o.pose.diagnostic;
      const fin = (v) => v !== null && v !== undefined && isFinite(v);
      if (o.pose.origin.length === 3) {  // 3-D: the frame's centre (_x, _y, _z) and rotation (_r00 .. _r22)
        const C = ['x', 'y', 'z'].map((a) => D[n + '_' + a]);
        const R = [0, 1, 2].map((r) => [0, 1, 2].map((q) => D[n + '_r' + r + q]));
        if (C.every(fin) && R.every((row) => row.every(fin))) {
          const [ox, oy, oz] = o.pose.origin, R0 = o.pose.R0, out = new Float32Array(data.length);
          for (let i = 0; i < data.length; i += 3) {
            const x = data[i] - ox, y = data[i + 1] - oy, z = data[i + 2] - oz;
            const l = [0, 1, 2].map((k) => R0[0][k] * x + R0[1][k] * y + R0[2][k] * z);  // R0^T (p - c0)
            for (let k = 0; k < 3; k++) out[i + k] = C[k] + R[k][0] * l[0] + R[k][1] * l[1] + R[k][2] * l[2];
          }
          return out;
        }
        return data;
      }
      const cx = D[n + '_x'], cy = D[n + '_y'], an = D[n + '_angle'];
      if ([cx, cy, an].every((v) => v !== null && v !== undefined && isFinite(v))) {
        const a = an * Math.PI / 180, c = Math.cos(a), s = Math.sin(a), [ox, oy] = o.pose.origin, R0 = o.pose.R0;
        const out = new Float32Array(data.length);
        for (let i = 0; i < data.length; i += 3) {
          const x = data[i] - ox, y = data[i + 1] - oy;
          const lx = R0[0][0] * x + R0[1][0] * y, ly = R0[0][1] * x + R0[1][1] * y;  // R0^T (p - c0)
          out[i] = cx + c * lx - s * ly; out[i + 1] = cy + s * lx + c * ly; out[i + 2] = data[i + 2];
        }
        return out;
      }
    }
    if (!o.turn || !data.length) return data;
    const d = S.frame && S.frame.meta.diagnostics ? S.frame.meta.diagnostics[o.turn.diagnostic] : null;
    if (d === null || d === undefined || !isFinite(d) || d === 0) return data;
    const a = o.turn.sign * d * Math.PI / 180, c = Math.cos(a), s = Math.sin(a), [qx, qy] = o.turn.about, out = new Float32Array(data.length);
    for (let i = 0; i < data.length; i += 3) {
      const x = data[i] - qx, y = data[i + 1] - qy;
      out[i] = qx + c * x - s * y; out[i + 1] = qy + s * x + c * y; out[i + 2] = data[i + 2];
    }
    return out;
  }
  const PIPS = { 1: [[0, 0]], 2: [[-1, -1], [1, 1]], 3: [[-1, -1], [0, 0], [1, 1]], 4: [[-1, -1], [-1, 1], [1, -1], [1, 1]],
    5: [[-1, -1], [-1, 1], [1, -1], [1, 1], [0, 0]], 6: [[-1, -1], [-1, 0], [-1, 1], [1, -1], [1, 0], [1, 1]] };
  function bodyGeometry(body, pose) {  // a box body: {edges, faces: [{tris, normal}], pips}
    const h = pad3(body.half_extents || [0.01, 0.01, 0.01]), pos = pad3(pose.position), q = pose.orientation || [1, 0, 0, 0];
    const tf = (p) => { const r = rotate(q, p); return [r[0] + pos[0], r[1] + pos[1], r[2] + pos[2]]; };
    const lo = h.map((x) => -x);
    const edges = boxEdges(lo, h, tf).flat();
    const faces = [], pips = [];
    const faceMap = body.faces || {};
    for (let a = 0; a < 3; a++) for (const s of [-1, 1]) {
      if (S.dim === 2 && a === 2 && s === -1) continue;  // a 2-D box: its one face
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
  // the scene's bounds: the container, else the obstacles, else (first frame) the quantisation box
  function sceneBounds(frameMeta) {
    const sc = S.scene || {}, c = sc.container;
    if (c && c.type === 'sphere') { const C = pad3(c.center || [0, 0, 0]); return [C.map((x) => x - c.radius), C.map((x) => x + c.radius)]; }
    if (c && c.type === 'box') return [pad3(c.min), pad3(c.max)];
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (const o of S.obstacles || []) for (let i = 0; i < o.lines.length; i += 3) for (let k = 0; k < 3; k++) {
      lo[k] = Math.min(lo[k], o.lines[i + k]); hi[k] = Math.max(hi[k], o.lines[i + k]);
    }
    if (frameMeta) for (let k = 0; k < S.dim; k++) { lo[k] = Math.min(lo[k], frameMeta.lo[k]); hi[k] = Math.max(hi[k], frameMeta.hi[k]); }
    if (!isFinite(lo[0])) return null;
    for (let k = 0; k < 3; k++) if (!isFinite(lo[k])) { lo[k] = hi[k] = 0; }
    return [lo, hi];
  }
  function setupCamera(frameMeta) {
    const b = sceneBounds(frameMeta);
    if (!b) return false;
    const [lo, hi] = b, centre = lo.map((x, i) => (x + hi[i]) / 2), half = hi.map((x, i) => Math.max((x - lo[i]) / 2, 1e-9));
    const extent = Math.max(...half.slice(0, S.dim));
    Object.assign(S.cam, { target: centre, extent, dist: extent * 3.4, pan: [centre[0], centre[1]], zoom: 1, half });
    S.cameraSet = true;
    return true;
  }
  function view2d() {  // half width and height of the 2-D view
    const aspect = canvas.width / Math.max(1, canvas.height), cam = S.cam;
    const hy = Math.max(cam.half[1], cam.half[0] / aspect) * 1.06 / cam.zoom;
    return [hy * aspect, hy];
  }
  function matrices() {
    const w = canvas.width, hgt = canvas.height, aspect = w / Math.max(1, hgt), cam = S.cam;
    if (S.dim === 2) {
      const [hx, hy] = view2d();
      return { view: lookAt([cam.pan[0], cam.pan[1], 1], [cam.pan[0], cam.pan[1], 0], [0, 1, 0]),
        proj: ortho(-hx, hx, -hy, hy, 0.01, 10), scale: hgt / (2 * hy), persp: 0, right: [1, 0, 0], up: [0, 1, 0] };
    }
    const up = upAxis(), k = up.k, e1 = (k + 1) % 3, e2 = (k + 2) % 3;
    const eye = cam.target.slice(), upv = [0, 0, 0]; upv[k] = up.sign;
    eye[e1] += cam.dist * Math.cos(cam.el) * Math.cos(cam.az);
    eye[e2] += cam.dist * Math.cos(cam.el) * Math.sin(cam.az);
    eye[k] += up.sign * cam.dist * Math.sin(cam.el);
    const fovy = 0.7, view = lookAt(eye, cam.target, upv);
    return { view, proj: perspective(fovy, aspect, cam.dist * 0.05, cam.dist * 10),
      scale: hgt / (2 * Math.tan(fovy / 2)), persp: 1, right: [view[0], view[4], view[8]], up: [view[1], view[5], view[9]] };
  }
  // a world point's CSS pixel on the canvas (tests use it to look at what is drawn where)
  S.toPixel = function (p) {
    const M = matrices(), v = mulVec(M.proj, mulVec(M.view, pad3(p)));
    const x = v[0] / v[3], y = v[1] / v[3];
    return [(x + 1) / 2 * canvas.clientWidth, (1 - y) / 2 * canvas.clientHeight];
  };

  // the outline of obstacle k as last drawn (segment end points, x y z each)
  S.obstacleOutline = (k) => Array.from((S.obstacles[k] || {}).drawn || []);

  // ---- drawing -----------------------------------------------------------------------------
  let staticLines = new Float32Array(0), nPoints = 0, hasColor = false, dirty = true, newFrame = false;
  function drawLines(data, mode, color, size, round) {
    if (!data.length) return;
    gl.bindVertexArray(lineVao); gl.bindBuffer(gl.ARRAY_BUFFER, lineBuf);
    gl.bufferData(gl.ARRAY_BUFFER, data instanceof Float32Array ? data : new Float32Array(data), gl.STREAM_DRAW);
    gl.uniform4fv(L.u.uColor, color); gl.uniform1f(L.u.uPointSize, size || 1); gl.uniform1i(L.u.uRound, round ? 1 : 0);
    gl.drawArrays(mode, 0, data.length / 3);
  }
  let upload = null;
  function uploadFrame() {
    const u = upload; upload = null;
    gl.bindVertexArray(pointVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, posBuf); gl.bufferData(gl.ARRAY_BUFFER, u.q, gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(P.aPos);
    gl.vertexAttribPointer(P.aPos, u.dim, gl.UNSIGNED_SHORT, true, 0, 0);  // a 2-D frame's z: the default 0
    hasColor = u.color;
    if (hasColor) {
      gl.bindBuffer(gl.ARRAY_BUFFER, colBuf); gl.bufferData(gl.ARRAY_BUFFER, new Uint8Array(u.buf, u.off, u.n), gl.DYNAMIC_DRAW);
      gl.enableVertexAttribArray(P.aCol); gl.vertexAttribPointer(P.aCol, 1, gl.UNSIGNED_BYTE, true, 0, 0);
    } else if (P.aCol >= 0) { gl.disableVertexAttribArray(P.aCol); gl.vertexAttrib1f(P.aCol, 0.5); }
    gl.bindVertexArray(null);
    nPoints = u.n;
  }
  function draw() {
    dirty = false;
    if (upload) uploadFrame();
    const dpr = window.devicePixelRatio || 1, w = Math.round(canvas.clientWidth * dpr), h = Math.round(canvas.clientHeight * dpr);
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(0.078, 0.086, 0.11, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (!S.header) return;
    gl.enable(gl.DEPTH_TEST);
    const M = matrices(), f = S.frame;
    if (f && nPoints && !S.skipParticles) {  // (skipParticles: the benchmark's transfer-only figure)
      gl.useProgram(P.p); gl.bindVertexArray(pointVao);
      const lo = pad3(f.meta.lo), hi = pad3(f.meta.hi);
      gl.uniform3fv(P.u.uLo, lo); gl.uniform3fv(P.u.uSpan, hi.map((x, i) => x - lo[i]));
      gl.uniformMatrix4fv(P.u.uView, false, M.view); gl.uniformMatrix4fv(P.u.uProj, false, M.proj);
      gl.uniform1f(P.u.uRadius, S.sizeScale * ((S.scene && S.scene.particle_radius) || S.header.particle_radius || S.cam.extent / 80));
      gl.uniform1f(P.u.uScale, M.scale); gl.uniform1f(P.u.uPersp, M.persp);
      gl.uniform1i(P.u.uDim, S.dim); gl.uniform1i(P.u.uHasCol, hasColor ? 1 : 0);
      gl.drawArrays(gl.POINTS, 0, nPoints);
    }
    gl.useProgram(L.p);
    gl.uniformMatrix4fv(L.u.uView, false, M.view); gl.uniformMatrix4fv(L.u.uProj, false, M.proj);
    drawLines(staticLines, gl.LINES, [0.55, 0.6, 0.7, 1]);
    // obstacles: 2-D ones filled over the particles' plane, all outlined
    let nob = 0;
    if (S.dim === 2) gl.disable(gl.DEPTH_TEST);
    for (const o of S.obstacles || []) {
      if (o.fill.length) drawLines(turned(o, o.fill), gl.TRIANGLES, [0.78, 0.80, 0.84, 1]);
      o.drawn = turned(o, o.lines);
      drawLines(o.drawn, gl.LINES, [0.95, 0.96, 1.0, 1]);
      nob++;
    }
    S.obstaclesDrawn = nob;
    // rigid bodies, posed by the frame
    let nb = 0;
    for (const body of ((S.scene && S.scene.bodies) || [])) {
      const pose = f && f.meta.rigid && f.meta.rigid[body.name];
      if (!pose) continue;
      if (body.shape === 'box') {
        const g = bodyGeometry(body, pose);
        for (const face of g.faces) {
          const shade = 0.55 + 0.45 * Math.max(0, dot(norm(face.normal), norm([0.4, 0.5, 0.8])));
          drawLines(face.tris, gl.TRIANGLES, [0.96 * shade, 0.94 * shade, 0.88 * shade, 1]);
        }
        drawLines(g.edges, gl.LINES, [0.1, 0.1, 0.12, 1]);
        const hx = pad3(body.half_extents || [0.01])[0];
        const pipPx = Math.max(2, (hx * 0.35) * M.scale / (M.persp ? S.cam.dist : 1));
        drawLines(g.pips, gl.POINTS, [0.08, 0.08, 0.1, 1], pipPx, true);
        nb++;
      } else if (body.shape === 'sphere' && body.radius > 0) {
        const out = []; sphereLines(out, pad3(pose.position), body.radius);
        drawLines(out, gl.LINES, [0.96, 0.94, 0.88, 1]); nb++;
      }
    }
    S.bodiesDrawn = nb;
    gl.enable(gl.DEPTH_TEST);
    if (newFrame) {  // the server sends the next frame once this one is drawn
      S.drawn++; S.drawnIndex = f ? f.index : -1; drawTimes.push(performance.now()); newFrame = false;
      send({ type: 'ready' });
    }
  }
  const drawTimes = [], recvTimes = [];
  function rate(times) {  // events per second over the last second
    const now = performance.now();
    while (times.length && now - times[0] > 1000) times.shift();
    if (times.length < 2) return times.length;
    return (times.length - 1) / Math.max(1e-3, (times[times.length - 1] - times[0]) / 1000);
  }
  // S.redraw (benchmarks/live_draw_rate.py): draw every animation frame, counted in S.redraws,
  // to time the drawing apart from the transfer
  S.redraws = 0;
  function frameLoop() { if (dirty || S.redraw) { draw(); S.redraws++; } requestAnimationFrame(frameLoop); }
  setInterval(() => {
    S.drawRate = rate(drawTimes); S.receiveRate = rate(recvTimes);
    $('draw-rate').textContent = S.drawRate ? S.drawRate.toFixed(1) : '–';
  }, 250);

  // ---- the connection ----------------------------------------------------------------------
  const token = new URLSearchParams(location.search).get('token');
  const wsUrl = (location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws' + (token ? '?token=' + encodeURIComponent(token) : '');
  let ws = null;
  function send(msg) { if (ws && ws.readyState === 1) { ws.send(JSON.stringify(msg)); S.sent++; } }
  function onHello(h) {
    S.hello = h; S.mode = h.mode; S.header = h.header || {}; S.scene = h.scene || null;
    S.dim = S.header.dim || (S.scene && S.scene.dim) || 3; S.nFrames = h.frames || 0;
    S.paused = !!h.paused;
    if (!S.scene) S.warnings.push('the run header describes no scene geometry the page can draw');
    S.obstacles = prepareObstacles();
    setupCamera(null);
    staticLines = new Float32Array(containerLines());
    $('title').textContent = `${S.header.scene || (S.scene && S.scene.name) || 'run'} (${S.header.kind || '?'}, ${S.dim}-D) · ${h.mode === 'live' ? 'live' : 'recorded'}`;
    const sel = $('color-by');
    for (const name of h.fields || []) { const o = document.createElement('option'); o.value = o.textContent = name; sel.appendChild(o); }
    // the server's choice for this kind (the header's render entry), else density, else the first
    sel.value = (h.fields || []).includes(h.color) ? h.color
      : ((h.fields || []).includes('density') ? 'density' : ((h.fields || [])[0] || ''));
    const ctl = h.controls || {};
    if (h.mode === 'live') {
      $('live-controls').hidden = false;
      S.control = {};
      for (const [k, n] of Object.entries(ctl)) S.control[k] = ((h.control || {})[k] || new Array(n).fill(0)).slice();
      S.base = JSON.parse(JSON.stringify(S.control));  // what the keys and sliders set (a drag adds to it)
      S.shakeable = Array.isArray(S.control.acceleration) && S.control.acceleration.length >= 2;
      $('control-line').hidden = !S.shakeable;
      $('shake-help').hidden = !S.shakeable; $('shake-drag-box').hidden = !S.shakeable;
      buildSliders(h.sliders || []);
      showControl();
      $('pause').textContent = S.paused ? 'resume' : 'pause';
    } else {
      $('playback').hidden = false; $('rate-line').hidden = true;
      $('scrub').max = Math.max(0, S.nFrames - 1);
    }
    $('help-drag').textContent = S.dim === 2 ? 'drag: pan · wheel: zoom at the cursor · double-click: fit'
      : 'drag: orbit · right-drag: pan · wheel: zoom · double-click: fit';
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
    // the arrays go to the GPU when the frame is drawn (a frame replaced before then never does)
    upload = { q: new Uint16Array(buf, off, n * dim), off: off + n * dim * 2 + (((4 - ((n * dim * 2) % 4)) % 4)), buf, n, dim,
      color: cb === 1 && !!meta.color };
    S.frame = { index, step, time, n, dim, meta };
    if (!S.cameraSet) setupCamera(meta);
    S.framesReceived++; S.lastIndex = index; S.lastStep = step; S.pending = false;
    recvTimes.push(performance.now());
    if (meta.paused !== undefined && S.mode === 'live') { S.paused = !!meta.paused; $('pause').textContent = S.paused ? 'resume' : 'pause'; }
    updateOverlay(); dirty = true; newFrame = true;
  }
  function fmt(x, d) { return x === null || x === undefined || !isFinite(x) ? '–' : (+x).toFixed(d); }
  function num(x) {
    if (x === null || x === undefined || !isFinite(x)) return '–';
    if (Number.isInteger(x) && Math.abs(x) < 1e9) return x.toLocaleString('en');
    const a = Math.abs(x); return a !== 0 && (a < 1e-3 || a >= 1e5) ? (+x).toExponential(3) : (+x).toPrecision(4);
  }
  function unit(name) { const u = (S.header.units || {})[name]; return u && u !== 'count' ? ` ${u}` : ''; }
  function updateOverlay() {
    const f = S.frame, m = f.meta;
    $('sim-time').textContent = fmt(f.time, 4); $('sim-step').textContent = f.step.toLocaleString('en');
    $('frame-index').textContent = S.mode === 'view' ? `${f.index + 1}/${S.nFrames}` : String(f.index);
    $('frame-counter').textContent = String(S.framesReceived);
    $('steps-rate').textContent = m.steps_per_second ? Math.round(m.steps_per_second).toLocaleString('en') : '–';
    $('particle-count').textContent = f.n.toLocaleString('en');
    const body = ((S.scene && S.scene.bodies) || []).find((b) => b.faces);
    let ans = m.result && m.result.answer ? { face: m.result.answer_face, answer: m.result.answer } : null;
    if (!ans && body) ans = answerOf(body, m.rigid && m.rigid[body.name], S.header.window);
    if (ans) { $('answer-line').hidden = false; $('answer').textContent = `${ans.answer} (face ${ans.face})`; }
    // forces, where the scene has them: this frame's lift and drag, and the averaged coefficients
    const d = m.diagnostics || {}, r = m.result || {};
    const hasForces = 'lift' in d || 'drag' in d;
    $('forces-line').hidden = !hasForces;
    if (hasForces) { $('lift').textContent = num(d.lift) + unit('lift'); $('drag').textContent = num(d.drag) + unit('drag'); }
    const hasCoef = (r.cl !== undefined && r.cl !== null) || (r.cd !== undefined && r.cd !== null);
    $('coef-line').hidden = !hasCoef;
    if (hasCoef) {
      const pm = (k) => num(r[k]) + (r[k + '_se'] !== null && r[k + '_se'] !== undefined && isFinite(r[k + '_se']) ? ` ± ${num(r[k + '_se'])}` : '');
      $('coef').textContent = `C_L ${pm('cl')} · C_D ${pm('cd')}` + (r.blocks ? ` (${r.blocks} blocks)` : '');
    }
    // every other diagnostic, generically
    const rows = Object.entries(d).filter(([k]) => k !== 'lift' && k !== 'drag');
    const box = $('diagnostics'); box.hidden = !rows.length;
    box.textContent = rows.map(([k, v]) => `${k} ${num(v)}${unit(k)}`).join(' · ');
    if (S.mode === 'view') { $('scrub').value = f.index; }
    else {
      $('status').textContent = S.paused ? 'paused' : 'running';
      if (m.control && !S.dragging && !S.sliding) syncSliders(m.control);
    }
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

  // ---- control: keys, sliders, drag ----------------------------------------------------------
  $('color-by').addEventListener('change', (e) => send({ type: 'color', field: e.target.value || null }));
  $('pause').addEventListener('click', () => togglePause());
  function togglePause() {
    if (S.mode !== 'live') return;
    S.paused = !S.paused; send({ type: S.paused ? 'pause' : 'resume' });
    $('pause').textContent = S.paused ? 'resume' : 'pause'; $('status').textContent = S.paused ? 'paused' : 'running';
  }
  function showControl() {
    const c = S.control || {};
    $('control').textContent = ['acceleration', 'torque'].filter((k) => c[k])
      .map((k) => `${k === 'acceleration' ? 'a' : 'τ'}=(${c[k].map((x) => x.toFixed(3)).join(', ')})`).join(' ');
  }
  function clampNorm(v, lim) { const l = Math.hypot(...v); if (l > lim) for (let i = 0; i < v.length; i++) v[i] *= lim / l * 0.999; return v; }
  const limit = (name) => (S.hello.limits || {})[name] || 100;
  // the control sent: what the keys and sliders set, plus a drag's shake
  function sendControl(names) {
    const msg = { type: 'control' };
    for (const k of names) {
      const v = S.base[k].slice();
      if (k === 'acceleration' && S.dragging && S.dragging.shake) for (let i = 0; i < v.length; i++) v[i] += S.dragging.accel[i] || 0;
      S.control[k] = clampNorm(v, limit(k)); msg[k] = S.control[k];
    }
    send(msg); showControl();
  }
  let throttle = null, throttled = new Set();
  function sendSoon(names) {  // at most one control message per 50 ms (the last one always goes)
    names.forEach((n) => throttled.add(n));
    if (throttle) return;
    sendControl([...throttled]); throttled.clear();
    throttle = setTimeout(() => { throttle = null; if (throttled.size) sendSoon([]); }, 50);
  }
  const KEYS = { w: ['acceleration', 1, 1], s: ['acceleration', 1, -1], a: ['acceleration', 0, -1], d: ['acceleration', 0, 1],
    e: ['acceleration', 2, 1], q: ['acceleration', 2, -1], i: ['torque', 0, 1], k: ['torque', 0, -1],
    l: ['torque', 1, 1], j: ['torque', 1, -1], o: ['torque', 2, 1], u: ['torque', 2, -1] };
  const STEP = { acceleration: 2.0, torque: 0.005 };
  window.addEventListener('keydown', (e) => {
    if (S.mode !== 'live' || !S.control || e.target.tagName === 'SELECT' || e.target.tagName === 'INPUT') return;
    const key = e.key.toLowerCase();
    if (key === 'p') { togglePause(); return; }
    let names;
    if (key === ' ') {
      names = Object.keys(S.control).filter((k) => k === 'acceleration' || k === 'torque');
      if (!names.length) return;
      for (const k of names) S.base[k].fill(0);
    } else if (KEYS[key] && S.base[KEYS[key][0]] && KEYS[key][1] < S.base[KEYS[key][0]].length) {
      const [name, axis, sign] = KEYS[key], v = S.base[name];
      v[axis] += sign * (STEP[name] || 1); clampNorm(v, limit(name));
      names = [name];
    } else return;
    e.preventDefault();
    sendControl(names);
  });
  function buildSliders(list) {
    const box = $('sliders'); box.textContent = ''; S.sliders = [];
    for (const sl of list) {
      const row = document.createElement('label'); row.className = 'slider';
      const name = document.createElement('span'); name.textContent = sl.label;
      const input = document.createElement('input');
      Object.assign(input, { type: 'range', min: sl.min, max: sl.max, step: sl.step || (sl.max - sl.min) / 100 });
      input.dataset.control = sl.control; input.id = `slider-${sl.control}-${sl.index || 0}`;
      const val = document.createElement('span'); val.className = 'slider-value';
      row.append(name, input, val); box.appendChild(row);
      const entry = { spec: sl, input, val };
      const set = (v) => { input.value = v; val.textContent = `${(+v).toPrecision(3)}${sl.unit ? ' ' + sl.unit : ''}`; };
      entry.set = set;
      const cur = S.base[sl.control] ? S.base[sl.control][sl.index || 0] : null;
      set(cur === null || cur === undefined ? sl.value : (cur - (sl.offset || 0)) / (sl.scale || 1));
      input.addEventListener('input', () => {
        S.sliding = true; clearTimeout(entry.t); entry.t = setTimeout(() => { S.sliding = false; }, 500);
        set(input.value);
        S.base[sl.control][sl.index || 0] = (sl.scale || 1) * +input.value + (sl.offset || 0);
        sendSoon([sl.control]);
      });
      S.sliders.push(entry);
    }
    box.hidden = !list.length;
  }
  function syncSliders(control) {  // the run's control (another page may have moved it)
    for (const e of S.sliders || []) {
      const v = control[e.spec.control]; if (!v) continue;
      const x = v[e.spec.index || 0]; if (x === null || x === undefined) continue;
      S.base[e.spec.control][e.spec.index || 0] = x;
      e.set((x - (e.spec.offset || 0)) / (e.spec.scale || 1));
    }
  }
  $('shake-drag').addEventListener('change', (e) => { S.shakeDrag = e.target.checked; });
  // the drawn size of the particles (a view setting: 1 = their radius)
  S.sizeScale = 1;
  S.setSize = (x) => { S.sizeScale = +x; $('size').value = x; $('size-value').textContent = `${(+x).toFixed(2)}×`; dirty = true; };
  $('size').addEventListener('input', (e) => S.setSize(e.target.value));

  // ---- pointer: orbit / pan / zoom, and shaking by dragging -----------------------------------
  const SHAKE_GAIN = 0.25;  // m/s² of container acceleration per CSS pixel dragged
  canvas.addEventListener('contextmenu', (e) => e.preventDefault());
  canvas.addEventListener('pointerdown', (e) => {
    const shake = S.mode === 'live' && S.shakeable && (e.shiftKey || S.shakeDrag) && e.button === 0;
    S.dragging = { x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, button: e.button, shake, accel: [0, 0, 0] };
    canvas.setPointerCapture(e.pointerId);
    if (shake) { canvas.style.cursor = 'move'; $('status').textContent = 'shaking'; }
  });
  function endDrag() {
    if (!S.dragging) return;
    const shook = S.dragging.shake;
    S.dragging = null; canvas.style.cursor = '';
    if (shook) { sendControl(['acceleration']); $('status').textContent = S.paused ? 'paused' : 'running'; }
  }
  canvas.addEventListener('pointerup', endDrag);
  canvas.addEventListener('pointercancel', endDrag);
  canvas.addEventListener('pointermove', (e) => {
    const D = S.dragging; if (!D) return;
    const dx = e.clientX - D.x, dy = e.clientY - D.y; D.x = e.clientX; D.y = e.clientY;
    if (D.shake) {
      // the container is pushed along the drag, in the screen plane: acceleration grows with
      // the distance dragged from where the drag began, and stops on release
      const M = matrices(), ox = (e.clientX - D.x0) * SHAKE_GAIN, oy = -(e.clientY - D.y0) * SHAKE_GAIN;
      const n = S.base.acceleration.length;
      D.accel = [0, 1, 2].slice(0, n).map((i) => ox * M.right[i] + oy * M.up[i]);
      sendSoon(['acceleration']);
      return;
    }
    if (S.dim === 2 || D.button === 2 || e.ctrlKey) {
      const s = S.dim === 2 ? 2 * view2d()[1] / canvas.clientHeight : 2 * S.cam.dist * Math.tan(0.35) / canvas.clientHeight;
      if (S.dim === 2) { S.cam.pan[0] -= dx * s; S.cam.pan[1] += dy * s; }
      else { const M = matrices(); for (let i = 0; i < 3; i++) S.cam.target[i] -= (dx * M.right[i] - dy * M.up[i]) * s; }
    } else {
      S.cam.az -= dx * 0.008; S.cam.el = Math.max(-1.5, Math.min(1.5, S.cam.el + dy * 0.008));
    }
    dirty = true;
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault(); const f = Math.exp(e.deltaY * 0.001);
    if (S.dim === 2) {  // zoom about the point under the cursor
      const r = canvas.getBoundingClientRect(), [hx, hy] = view2d();
      const u = (e.clientX - r.left) / r.width * 2 - 1, v = 1 - (e.clientY - r.top) / r.height * 2;
      const wx = S.cam.pan[0] + u * hx, wy = S.cam.pan[1] + v * hy;
      S.cam.zoom = Math.max(0.05, Math.min(1e4, S.cam.zoom / f));
      const [hx2, hy2] = view2d();
      S.cam.pan[0] = wx - u * hx2; S.cam.pan[1] = wy - v * hy2;
    } else S.cam.dist *= f;
    dirty = true;
  }, { passive: false });
  canvas.addEventListener('dblclick', () => { S.cameraSet = false; setupCamera(S.frame && S.frame.meta); dirty = true; });
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
