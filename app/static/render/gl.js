// WebGL2 plumbing for the browser renderer: the context and what it must support, float textures, and the
// render targets that draw into them (made once per set of attachments and kept until a texture of them is
// released). Nothing here knows cameras or planes; programs are passes (pass.js).

/** Extensions the renderer needs beyond WebGL2 core: float render targets (cost layers, sums, states). */
export const REQUIRED_EXTENSIONS = ["EXT_color_buffer_float"];

/**
 * What this browser offers: { ok, reason, gpu, software } for a canvas (or an OffscreenCanvas).
 * gpu: the unmasked renderer string where the browser tells it; software: a CPU rasteriser (SwiftShader,
 * llvmpipe) stands behind WebGL, so the server is likely faster.
 */
export function capabilities(canvas) {
  const gl = canvas.getContext("webgl2", { antialias: false, depth: false, stencil: false, preserveDrawingBuffer: true });
  if (!gl) return { ok: false, reason: "this browser has no WebGL2", gpu: null, software: false };
  const missing = REQUIRED_EXTENSIONS.filter((name) => !gl.getExtension(name));
  const gpu = rendererName(gl);
  const software = isSoftware(gl);
  if (missing.length) return { ok: false, reason: `WebGL2 lacks ${missing.join(", ")}`, gpu, software, gl };
  return { ok: true, reason: null, gpu, software, gl };
}

/** The GPU's name where the browser tells it (else the masked renderer string). */
export function rendererName(gl) {
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  return info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
}

/** Whether a CPU rasteriser (SwiftShader, llvmpipe) stands behind ``gl``. */
export function isSoftware(gl) {
  return /swiftshader|llvmpipe|software|basic render/i.test(rendererName(gl) || "");
}

/** Formats of the textures the passes render into or read. */
export const FORMATS = {
  rgba32f: { internal: "RGBA32F", format: "RGBA", type: "FLOAT" },
  rg32f: { internal: "RG32F", format: "RG", type: "FLOAT" },
  r32f: { internal: "R32F", format: "RED", type: "FLOAT" },
  rgba8: { internal: "RGBA8", format: "RGBA", type: "UNSIGNED_BYTE" },
  r8: { internal: "R8", format: "RED", type: "UNSIGNED_BYTE" },
};

let nextId = 1; // names the GL objects of the records below in render-target keys

/** A w x h 2D texture of ``kind`` (a FORMATS key), nearest sampling, clamped; contents undefined. */
export function texture2d(gl, kind, w, h) {
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.texStorage2D(gl.TEXTURE_2D, 1, gl[FORMATS[kind].internal], w, h);
  nearest(gl, gl.TEXTURE_2D);
  return { texture: t, width: w, height: h, kind, id: nextId++ };
}

/** A w x h x layers array texture of ``kind``, nearest sampling, clamped. */
export function textureArray(gl, kind, w, h, layers) {
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D_ARRAY, t);
  gl.texStorage3D(gl.TEXTURE_2D_ARRAY, 1, gl[FORMATS[kind].internal], w, h, layers);
  nearest(gl, gl.TEXTURE_2D_ARRAY);
  return { texture: t, width: w, height: h, layers, kind, id: nextId++ };
}

/** A w x h float32 depth buffer (a scatter's: occlusion.js). */
export function depthBuffer(gl, w, h) {
  const r = gl.createRenderbuffer();
  gl.bindRenderbuffer(gl.RENDERBUFFER, r);
  gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT32F, w, h);
  return { renderbuffer: r, width: w, height: h, id: nextId++ };
}

function nearest(gl, target) {
  gl.texParameteri(target, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(target, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  gl.texParameteri(target, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(target, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
}

const targets = new WeakMap(); // gl -> Map(key of the attachments -> { fb, width, height, ids })

/** The render target drawing into ``attachments`` (each a 2D texture record, { tex, layer } of an array texture, or
 * null: that output location draws nowhere) and ``depth`` (a depthBuffer, or none): { fb, width, height }, made on
 * first use and kept until one of its textures is released. */
export function target(gl, attachments, depth = null) {
  if (!targets.has(gl)) targets.set(gl, new Map());
  const known = targets.get(gl);
  const key = [...attachments.map((t) => (t === null ? "-" : t.tex ? `${t.tex.id}:${t.layer}` : `${t.id}`)),
    depth ? `d${depth.id}` : ""].join(" ");
  if (!known.has(key)) known.set(key, framebuffer(gl, attachments, depth));
  return known.get(key);
}

function framebuffer(gl, attachments, depth) {
  const fb = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  attachments.forEach((t, i) => {
    if (t === null) return;
    if (t.tex) gl.framebufferTextureLayer(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, t.tex.texture, 0, t.layer);
    else gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, gl.TEXTURE_2D, t.texture, 0);
  });
  if (depth) gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth.renderbuffer);
  gl.drawBuffers(attachments.map((t, i) => (t === null ? gl.NONE : gl.COLOR_ATTACHMENT0 + i)));
  const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
  if (status !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`framebuffer incomplete (0x${status.toString(16)})`);
  const used = attachments.filter((t) => t !== null);
  const size = used[0].tex ?? used[0];
  const ids = new Set([...used.map((t) => (t.tex ?? t).id), ...(depth ? [depth.id] : [])]);
  return { fb, width: size.width, height: size.height, ids };
}

/** The canvas as a render target of width x height px. */
export function canvasTarget(width, height) {
  return { fb: null, width, height };
}

const placeholders = new WeakMap(); // gl -> { "2d", "array" }: 1 x 1 textures for samplers a pass leaves unused

/** An empty texture of ``kind`` ("2d" or "array") for a sampler that reads nothing. */
export function placeholder(gl, kind) {
  if (!placeholders.has(gl)) {
    placeholders.set(gl, { "2d": texture2d(gl, "rgba32f", 1, 1), array: textureArray(gl, "r32f", 1, 1, 1) });
  }
  return placeholders.get(gl)[kind];
}

/** Read a float texture (2D, RG/R/RGBA32F) back: Float32Array of width * height * channels, row 0 first. */
export function readFloat(gl, tex, channels) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, target(gl, [tex]).fb);
  const out = new Float32Array(tex.width * tex.height * 4);
  gl.readPixels(0, 0, tex.width, tex.height, gl.RGBA, gl.FLOAT, out);
  if (channels === 4) return out;
  const packed = new Float32Array(tex.width * tex.height * channels);
  for (let i = 0, n = tex.width * tex.height; i < n; i++) {
    for (let c = 0; c < channels; c++) packed[i * channels + c] = out[i * 4 + c];
  }
  return packed;
}

/** Read an RGBA8 texture back: Uint8Array of width * height * 4, row 0 first. */
export function readBytes(gl, tex) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, target(gl, [tex]).fb);
  const out = new Uint8Array(tex.width * tex.height * 4);
  gl.readPixels(0, 0, tex.width, tex.height, gl.RGBA, gl.UNSIGNED_BYTE, out);
  return out;
}

/** Delete textures and depth buffers (records; undefined or null ones are skipped) and the render targets that
 * draw into them. */
export function release(gl, ...records) {
  const ids = new Set();
  for (const r of records) {
    if (!r) continue;
    if (r.texture) gl.deleteTexture(r.texture);
    if (r.renderbuffer) gl.deleteRenderbuffer(r.renderbuffer);
    ids.add(r.id);
  }
  const known = targets.get(gl);
  if (!known) return;
  for (const [key, t] of known) {
    if (![...t.ids].some((id) => ids.has(id))) continue;
    gl.deleteFramebuffer(t.fb);
    known.delete(key);
  }
}
