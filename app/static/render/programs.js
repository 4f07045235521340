// The shader sources beside this module (./shaders/): fetched once per page, their ``#include "file"`` lines
// expanded (GLSL has none), compile-time constants prepended as #defines, compiled and linked into a program.

const SHADER_DIR = new URL("./shaders/", import.meta.url);
const sources = new Map(); // shader file name -> text (fetched once per page)
const INCLUDE = /^#include "([\w.]+)"$/gm;

/** The text of shader file ``name`` (fetched from ./shaders/ once). */
async function shaderSource(name) {
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

/** Shader file ``name`` with its ``#include "file"`` lines replaced by those files. */
function expand(name, seen = new Set()) {
  const text = sources.get(name);
  if (text === undefined) throw new Error(`shader ${name} was not loaded`);
  if (seen.has(name)) throw new Error(`shader ${name} includes itself`);
  return text.replace(INCLUDE, (_, inner) => expand(inner, new Set([...seen, name])));
}

/** The source of prefetched shader file ``name``, includes expanded, with ``defines`` ({NAME: value}) after its
 * version line. */
export function shaderText(name, defines = {}) {
  const text = expand(name);
  const end = text.indexOf("\n") + 1; // after "#version 300 es"
  const header = Object.entries(defines).map(([k, v]) => `#define ${k} ${v}\n`).join("");
  return text.slice(0, end) + header + text.slice(end);
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

/** A linked program of two shader sources (``names`` [vertex, fragment] for its messages). */
export function link(gl, vertexText, fragmentText, names) {
  const p = gl.createProgram();
  const vs = compile(gl, gl.VERTEX_SHADER, vertexText, names[0]);
  const fs = compile(gl, gl.FRAGMENT_SHADER, fragmentText, names[1]);
  gl.attachShader(p, vs);
  gl.attachShader(p, fs);
  gl.linkProgram(p);
  gl.deleteShader(vs);
  gl.deleteShader(fs);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`program ${names[1]}: ${gl.getProgramInfoLog(p)}`);
  return p;
}
