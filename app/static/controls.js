// The page's controls (index.html) as what they ask of a view: its size, the renderer's options, the quality level,
// the overlay. Their choices, defaults and the planes' limit come from the hello's ``controls``
// (workers/streaming/rules.py viewpoint_controls); index.html only labels the choices.

const $ = (id) => document.getElementById(id);
const MENUS = { method: "method", aggregation: "aggregation", occlusions: "occlusions", overlay: "overlay",
  quality: "render_quality" }; // element id -> the Viewpoint field it chooses

export class Controls {
  constructor() {
    this.offered = null; // the hello's controls, once one came
    this.levels = {}; // the hello's quality levels: level -> the options it sets
  }

  /** Offer the ``hello``'s choices in the menus and its planes limit; the first hello's defaults select. */
  offer(hello) {
    const first = this.offered === null;
    this.offered = hello.controls;
    this.levels = hello.quality_levels;
    for (const [id, field] of Object.entries(MENUS)) {
      offerChoices($(id), this.offered.choices[field], first ? this.offered.defaults[field] ?? "" : $(id).value);
    }
    $("planes").max = this.offered.planes.max;
    if (first) $("planes").value = this.offered.defaults.planes;
  }

  /** The hello's default of Viewpoint field ``name``. */
  defaultOf(name) {
    return this.offered.defaults[name];
  }

  /** [width, height] of the view (px). */
  get size() {
    return $("size").value.split("x").map(Number);
  }

  /** The quality level asked for: "auto", "best" or "fast". */
  get quality() {
    return $("quality").value;
  }

  get overlay() {
    return $("overlay").value;
  }

  /** D_bnd from the slider; null: derived from the rig (the server's rule, applied where the view is rendered). */
  get dBnd() {
    if ($("dbnd-auto").checked) return null;
    return Number(Math.pow(10, Number($("dbnd").value)).toPrecision(3));
  }

  /** The depth options the advanced switches set (aggregation, occlusions): null where they leave it to the level. */
  depthOptions() {
    return { aggregation: $("aggregation").value || null, occlusions: $("occlusions").value || null };
  }

  /** The renderer's options the page sets, those of the quality level apart. */
  pageOptions() {
    return { method: $("method").value, d_bnd: this.dBnd, planes: Number($("planes").value) || this.offered?.defaults.planes };
  }

  /** The renderer's options (RenderOptions' fields, ``fields``: their names) a viewpoint of the page asks for at
   * quality ``level`` ("best" or "fast"), as the server's session makes them (SweepSettings.render_fields): a
   * viewpoint's defaults under the page's switches, the level's where they leave them. Before a hello: the page's
   * switches alone. */
  renderOptions(level, fields = []) {
    const preset = this.levels[level] || {};
    const own = this.depthOptions();
    const depth = {};
    for (const key of Object.keys(own)) {
      const value = own[key] ?? preset[key];
      if (value) depth[key] = value;
    }
    const defaults = this.offered ? this.offered.defaults : {};
    const viewpoint = Object.fromEntries(fields.filter((k) => k in defaults).map((k) => [k, defaults[k]]));
    return { ...viewpoint, ...this.pageOptions(), ...depth };
  }

  /** What runs at ``level``, as a frame header's "quality" says it: the level, or "custom" where a switch differs. */
  levelRun(level) {
    const preset = this.levels[level] || {};
    const own = this.depthOptions();
    return Object.keys(own).some((k) => own[k] !== null && own[k] !== preset[k]) ? "custom" : level;
  }

  /** The server's default view size (width, height), selected (added to the sizes if new) until the user picks one. */
  startSize([width, height]) {
    const value = `${width}x${height}`;
    if (![...$("size").options].some((o) => o.value === value)) {
      const option = new Option(`${width}×${height}`, value);
      const after = [...$("size").options].find((o) => Number(o.value.split("x")[0]) > width);
      $("size").add(option, after || null);
    }
    $("size").value = value;
  }
}

/** Make ``values`` the options of ``select``, labelled as the page labels them (a value it has no label for by
 * itself), after its "" option (as the quality level) where it has one; ``selected`` is selected if offered. */
function offerChoices(select, values, selected) {
  const labels = new Map([...select.options].map((o) => [o.value, o.text]));
  const keep = labels.has("") ? ["", ...values] : values;
  select.replaceChildren(...keep.map((v) => new Option(labels.get(v) ?? v, v)));
  if (keep.includes(selected)) select.value = selected;
}
