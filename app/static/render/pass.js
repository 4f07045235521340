// One pass of the renderer: a shader program and how to run it. The program tells its own uniforms
// (getActiveUniform: name, type, array size), so each value is set with the setter of its type, and what does not
// fit fails loudly: a name no shader of the pass declares, a value of the wrong length, a sampler given a texture
// of the other kind, a uniform the program uses that was never given. Each sampler has a texture unit of its own
// and is bound at every draw (a sampler given null gets an empty texture of its kind: a unit left holding a texture
// that the pass renders into would make the draw fail). The shapes come from twgl.js's uniform setters and regl's
// commands; the code is ours.
import { placeholder } from "./gl.js";
import { link, shaderText } from "./programs.js";

/** Uniform type -> [numbers per element, setter, whether it takes floats]. */
function uniformTypes(gl) {
  const float = (per, setter) => [per, setter, true];
  const int = (per, setter) => [per, setter, false];
  return new Map([
    [gl.FLOAT, float(1, (l, v) => gl.uniform1fv(l, v))], [gl.FLOAT_VEC2, float(2, (l, v) => gl.uniform2fv(l, v))],
    [gl.FLOAT_VEC3, float(3, (l, v) => gl.uniform3fv(l, v))], [gl.FLOAT_VEC4, float(4, (l, v) => gl.uniform4fv(l, v))],
    [gl.FLOAT_MAT3, float(9, (l, v) => gl.uniformMatrix3fv(l, false, v))],
    [gl.FLOAT_MAT4, float(16, (l, v) => gl.uniformMatrix4fv(l, false, v))],
    [gl.INT, int(1, (l, v) => gl.uniform1iv(l, v))], [gl.INT_VEC2, int(2, (l, v) => gl.uniform2iv(l, v))],
    [gl.INT_VEC3, int(3, (l, v) => gl.uniform3iv(l, v))], [gl.INT_VEC4, int(4, (l, v) => gl.uniform4iv(l, v))],
    [gl.BOOL, int(1, (l, v) => gl.uniform1iv(l, v))],
  ]);
}
const DECLARED = /^\s*uniform\s+(?:(?:lowp|mediump|highp)\s+)?\w+\s+(\w+)/gm;

export class Pass {
  /** The program of shader files ``fragment`` and ``vertex`` (prefetched: programs.js loadShaders) compiled with
   * ``defines`` ({NAME: value}). */
  constructor(gl, fragment, { vertex = "fullscreen.vert", defines = {} } = {}) {
    this.gl = gl;
    this.name = fragment;
    const texts = [shaderText(vertex, defines), shaderText(fragment, defines)];
    this.program = link(gl, ...texts, [vertex, fragment]);
    this.declared = new Set(texts.flatMap((t) => [...t.matchAll(DECLARED)].map((m) => m[1])));
    this.uniforms = new Map(); // name -> { type, size, location, unit (samplers) }
    this.textures = new Map(); // sampler name -> the texture record given (null: none)
    this.given = new Set();
    this.types = uniformTypes(gl);
    const samplers = new Map([[gl.SAMPLER_2D, "2d"], [gl.SAMPLER_2D_ARRAY, "array"]]);
    let units = 0;
    gl.useProgram(this.program);
    for (let i = 0; i < gl.getProgramParameter(this.program, gl.ACTIVE_UNIFORMS); i++) {
      const info = gl.getActiveUniform(this.program, i);
      const name = info.name.replace(/\[0\]$/, "");
      const uniform = { type: info.type, size: info.size, location: gl.getUniformLocation(this.program, info.name) };
      if (samplers.has(info.type)) {
        Object.assign(uniform, { kind: samplers.get(info.type), unit: units++ });
        gl.uniform1i(uniform.location, uniform.unit);
      } else if (!this.types.has(info.type)) {
        throw new Error(`${this.name}: uniform ${name} has a type this pass cannot set (0x${info.type.toString(16)})`);
      }
      this.uniforms.set(name, uniform);
    }
  }

  /** Set uniforms by name: a number, a boolean or an array (nested arrays are flattened; an array uniform takes up
   * to its size of elements) for a value, a texture record (gl.js) or null for a sampler. A name the shaders
   * declare but the compiled program does not use is skipped. Returns this pass. */
  set(values) {
    const gl = this.gl;
    gl.useProgram(this.program);
    for (const [name, value] of Object.entries(values)) {
      if (!this.declared.has(name)) throw new Error(`${this.name} has no uniform ${name}`);
      const uniform = this.uniforms.get(name);
      if (!uniform) continue;
      if (uniform.kind) {
        if (value !== null && (value.layers === undefined) !== (uniform.kind === "2d")) {
          throw new Error(`${this.name}: sampler ${name} takes a ${uniform.kind === "2d" ? "2D" : "array"} texture`);
        }
        this.textures.set(name, value);
        continue;
      }
      const [per, setter, floats] = this.types.get(uniform.type);
      const numbers = (value?.length === undefined ? [value] : Array.from(value).flat(Infinity)).map(Number);
      if (numbers.length === 0 || numbers.length % per !== 0 || numbers.length / per > uniform.size
          || numbers.some(Number.isNaN)) {
        throw new Error(`${this.name}: uniform ${name} takes ${per} number(s) a value, at most ${uniform.size} values; `
          + `got ${JSON.stringify(value)}`);
      }
      setter(uniform.location, floats ? Float32Array.from(numbers) : Int32Array.from(numbers));
      this.given.add(name);
    }
    return this;
  }

  /** Run the fragment shader once per pixel of ``target`` ({ fb, width, height }: gl.js target, or fb null for the
   * canvas): one triangle covering the viewport, made by the vertex shader from gl_VertexID. */
  draw(target) {
    this.drawArrays(target, this.gl.TRIANGLES, 3);
  }

  /** Draw ``count`` points (the vertex shader places each by gl_VertexID) into ``target``. */
  drawPoints(target, count) {
    this.drawArrays(target, this.gl.POINTS, count);
  }

  drawArrays(target, mode, count) {
    const gl = this.gl;
    gl.useProgram(this.program);
    const bound = [];
    for (const [name, uniform] of this.uniforms) {
      if (uniform.kind) bound.push([uniform, this.texture(name, uniform)]);
      else if (!this.given.has(name)) throw new Error(`${this.name}: uniform ${name} was never set`);
    }
    // bound only now: making a placeholder binds it on the active unit
    for (const [uniform, texture] of bound) {
      gl.activeTexture(gl.TEXTURE0 + uniform.unit);
      gl.bindTexture(uniform.kind === "2d" ? gl.TEXTURE_2D : gl.TEXTURE_2D_ARRAY, texture.texture);
    }
    gl.bindFramebuffer(gl.FRAMEBUFFER, target.fb);
    gl.viewport(0, 0, target.width, target.height);
    gl.drawArrays(mode, 0, count);
  }

  /** The texture sampler ``name`` reads: the one given, or for null an empty one of its kind. */
  texture(name, uniform) {
    if (!this.textures.has(name)) throw new Error(`${this.name}: sampler ${name} was never given a texture (or null)`);
    return this.textures.get(name) ?? placeholder(this.gl, uniform.kind);
  }

  dispose() {
    this.gl.deleteProgram(this.program);
  }
}
