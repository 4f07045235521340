// WebGL2 plumbing for the browser renderer: the context and what it must support, programs built from
// the shader files beside this module, float textures and the framebuffers that render into them.
// Nothing here knows cameras or planes.

const SHADER_DIR = new URL("./shaders/", import.meta.url);
const sources = new Map(); // shader file name -> text (fetched once per page)

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

/** The text of shader file ``name`` (fetched from ./shaders/ once). */
export async function shaderSource(name) {
  if (!sources.has(name)) {
    const response = await fetch(new URL(name, SHADER_DIR));
    if (!response.ok) throw new Error(`shader ${name}: HTTP ${response.status}`);
    sources.set(name, await response.text());
  }
  return sources.get(name);
}

/** Prefetch shader files, and the files they include, so that program builds later are synchronous. */
export async function loadShaders(names) {
  const texts = await Promise.all(names.map(shaderSource));
  const included = texts.flatMap((t) => [...t.matchAll(INCLUDE)].map((m) => m[1]));
  if (included.length) await loadShaders([...new Set(included)].filter((n) => !sources.has(n)));
}

const INCLUDE = /^#include "([\w.]+)"$/gm;

/** Shader file ``name`` with its ``#include "file"`` lines replaced by those files (GLSL has no includes). */
function expand(name, seen = new Set()) {
  const text = sources.get(name);
  if (text === undefined) throw new Error(`shader ${name} was not loaded`);
  if (seen.has(name)) throw new Error(`shader ${name} includes itself`);
  return text.replace(INCLUDE, (_, inner) => expand(inner, new Set([...seen, name])));
}

function compile(gl, type, text, name) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, text);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
    const log = gl.getShaderInfoLog(shader);
    gl.deleteShader(shader);
    throw new Error(`shader ${name} does not compile: ${log}`);
  }
  return shader;
}

/**
 * A program from two prefetched shader files with ``defines`` ({NAME: value}) inserted after the
 * version line; returns { program, uniforms } where uniforms maps a name to its location (looked up lazily).
 */
export function program(gl, vertexName, fragmentName, defines = {}) {
  const header = Object.entries(defines).map(([k, v]) => `#define ${k} ${v}\n`).join("");
  const withDefines = (name) => {
    const text = expand(name);
    const end = text.indexOf("\n") + 1; // after "#version 300 es"
    return text.slice(0, end) + header + text.slice(end);
  };
  const p = gl.createProgram();
  const vs = compile(gl, gl.VERTEX_SHADER, withDefines(vertexName), vertexName);
  const fs = compile(gl, gl.FRAGMENT_SHADER, withDefines(fragmentName), fragmentName);
  gl.attachShader(p, vs);
  gl.attachShader(p, fs);
  gl.linkProgram(p);
  gl.deleteShader(vs);
  gl.deleteShader(fs);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`program ${fragmentName}: ${gl.getProgramInfoLog(p)}`);
  const cache = new Map();
  const uniforms = new Proxy({}, {
    get(_, key) {
      if (!cache.has(key)) cache.set(key, gl.getUniformLocation(p, key));
      return cache.get(key);
    },
  });
  return { program: p, uniforms };
}

/** Formats of the textures the passes render into or read. */
export const FORMATS = {
  rgba32f: { internal: "RGBA32F", format: "RGBA", type: "FLOAT" },
  rg32f: { internal: "RG32F", format: "RG", type: "FLOAT" },
  r32f: { internal: "R32F", format: "RED", type: "FLOAT" },
  rgba8: { internal: "RGBA8", format: "RGBA", type: "UNSIGNED_BYTE" },
  r8: { internal: "R8", format: "RED", type: "UNSIGNED_BYTE" },
};

/** A w x h 2D texture of ``kind`` (a FORMATS key), nearest sampling, clamped; contents undefined. */
export function texture2d(gl, kind, w, h) {
  const f = FORMATS[kind];
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.texStorage2D(gl.TEXTURE_2D, 1, gl[f.internal], w, h);
  nearest(gl, gl.TEXTURE_2D);
  return { texture: t, width: w, height: h, kind };
}

/** A w x h x layers array texture of ``kind``, nearest sampling, clamped. */
export function textureArray(gl, kind, w, h, layers) {
  const f = FORMATS[kind];
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D_ARRAY, t);
  gl.texStorage3D(gl.TEXTURE_2D_ARRAY, 1, gl[f.internal], w, h, layers);
  nearest(gl, gl.TEXTURE_2D_ARRAY);
  return { texture: t, width: w, height: h, layers, kind };
}

function nearest(gl, target) {
  gl.texParameteri(target, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(target, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  gl.texParameteri(target, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(target, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
}

/** A framebuffer drawing into ``targets``: each a 2D texture, { tex, layer } of an array texture, or null (that
 * output location draws nowhere). */
export function framebuffer(gl, targets) {
  const fb = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  targets.forEach((t, i) => {
    if (t === null) return;
    if (t.layer === undefined) gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, gl.TEXTURE_2D, t.texture, 0);
    else gl.framebufferTextureLayer(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, t.tex.texture, 0, t.layer);
  });
  gl.drawBuffers(targets.map((t, i) => (t === null ? gl.NONE : gl.COLOR_ATTACHMENT0 + i)));
  const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
  if (status !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`framebuffer incomplete (0x${status.toString(16)})`);
  const first = targets.find((t) => t !== null);
  const size = first.layer === undefined ? first : first.tex;
  return { fb, width: size.width, height: size.height };
}

/** Bind ``textures`` ({uniform name: texture record}) to units 0.. for program ``prog``. */
export function bindTextures(gl, prog, textures) {
  Object.entries(textures).forEach(([name, t], unit) => {
    gl.activeTexture(gl.TEXTURE0 + unit);
    gl.bindTexture(t.layers === undefined ? gl.TEXTURE_2D : gl.TEXTURE_2D_ARRAY, t.texture);
    gl.uniform1i(prog.uniforms[name], unit);
  });
}

/** Run ``prog``'s fragment shader once per pixel of ``target`` (a framebuffer record, or null with size for
 * the canvas): one triangle covering the viewport (the vertex shader makes it from gl_VertexID). */
export function drawFullscreen(gl, target, width, height) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, target ? target.fb : null);
  gl.viewport(0, 0, target ? target.width : width, target ? target.height : height);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
}

/** Read a float texture (2D, RG/R/RGBA32F) back: Float32Array of width * height * channels, row 0 first. */
export function readFloat(gl, tex, channels) {
  const fb = framebuffer(gl, [tex]);
  const out = new Float32Array(tex.width * tex.height * 4);
  gl.readPixels(0, 0, tex.width, tex.height, gl.RGBA, gl.FLOAT, out);
  gl.deleteFramebuffer(fb.fb);
  if (channels === 4) return out;
  const packed = new Float32Array(tex.width * tex.height * channels);
  for (let i = 0, n = tex.width * tex.height; i < n; i++) {
    for (let c = 0; c < channels; c++) packed[i * channels + c] = out[i * 4 + c];
  }
  return packed;
}

/** Read an RGBA8 texture back: Uint8Array of width * height * 4, row 0 first. */
export function readBytes(gl, tex) {
  const fb = framebuffer(gl, [tex]);
  const out = new Uint8Array(tex.width * tex.height * 4);
  gl.readPixels(0, 0, tex.width, tex.height, gl.RGBA, gl.UNSIGNED_BYTE, out);
  gl.deleteFramebuffer(fb.fb);
  return out;
}

/** Delete the GL objects of texture or framebuffer records (undefined ones are skipped). */
export function release(gl, ...records) {
  for (const r of records) {
    if (!r) continue;
    if (r.texture) gl.deleteTexture(r.texture);
    if (r.fb) gl.deleteFramebuffer(r.fb);
  }
}
