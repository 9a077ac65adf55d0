// keyframer review: the page. Every change posts the step list to the server, which runs it on
// the cached scores with the code `select` runs and answers with the keyframes and the timeline.
// No build step, no library; the token travels in a header (in the query only for images).
(function () {
  "use strict";
  const token = document.querySelector('meta[name="kf-token"]').content;
  const $ = (id) => document.getElementById(id);
  const S = {
    info: null, chain: [], schema: [], steps: [], savedSteps: "[]", revision: 0,
    sel: null, view: null, cursor: 0, undo: [], redo: [], showMask: false, series: null,
    exported: new Map(), applySeq: 0, inputAt: 0, saving: false,
  };
  window.addEventListener("error", (e) => {
    document.body.dataset.scriptError = String(e.message || e);
  });

  function say(text, bad) {
    const s = $("status");
    s.textContent = text;
    s.className = bad ? "bad" : "";
  }

  async function api(method, path, body) {
    const opts = { method, headers: { "X-Keyframer-Token": token } };
    if (body !== undefined) {
      opts.headers["Content-Type"] = "application/json";
      opts.body = JSON.stringify(body);
    }
    const r = await fetch(path, opts);
    const v = await r.json();
    if (!r.ok) {
      const e = new Error(v.error || r.statusText);
      e.status = r.status;
      e.step = v.step;
      throw e;
    }
    return v;
  }

  function img(path, size) {
    return path + (size ? "?size=" + size + "&" : "?") + "token=" + token;
  }

  // ----- steps -------------------------------------------------------------------------------
  const stepId = (s) => Object.keys(s)[0];
  const stepOf = (id) => S.steps.find((s) => stepId(s) === id);

  function coerce(text) {
    const t = text.trim();
    if (t === "") return null;
    if (t === "true" || t === "false") return t === "true";
    if (/^-?\d+(\.\d+)?([eE][-+]?\d+)?$/.test(t)) return Number(t);
    return t;
  }

  function ordered(steps) {
    const at = (s) => S.chain.findIndex((k) => k.id === stepId(s));
    return steps.slice().sort((a, b) => at(a) - at(b));
  }

  function commit(steps) {
    S.undo.push(JSON.stringify(S.steps));
    if (S.undo.length > 200) S.undo.shift();
    S.redo = [];
    S.steps = ordered(steps);
    renderSteps();
    apply();
  }

  // The text of a parameter's value in the editor (lists of frames as "60,61").
  function shown(v) {
    if (v === null || v === undefined) return "";
    return Array.isArray(v) ? v.join(",") : String(v);
  }

  // The value of an editor's text: the manual lists are frame lists.
  function parsed(plugin, text) {
    if (plugin !== "manual") return coerce(text);
    const parts = text.split(/[\s,]+/).filter((p) => p !== "");
    const nums = parts.map(Number);
    return nums.every((n) => Number.isInteger(n) && n >= 0) ? nums : text;
  }

  function renderSteps() {
    const form = $("steps");
    // The input being edited keeps its focus and its text across the redraw.
    const active = document.activeElement;
    const editing = active && form.contains(active) && active.name && active.closest("fieldset")
      ? { row: active.closest("fieldset").id, name: active.name, value: active.value,
          text: active.type === "text" } : null;
    form.textContent = "";
    const state = new Map(((S.sel && S.sel.steps_state) || []).map((s) => [s.plugin, s]));
    for (const plugin of S.chain.map((k) => k.id)) {
      const params = S.schema.filter((p) => p.plugin === plugin);
      if (params.length === 0 && plugin !== "manual") continue;
      const step = stepOf(plugin);
      const row = document.createElement("fieldset");
      row.id = "step-" + plugin;
      const st = step ? state.get(plugin) : undefined;
      if (st && !st.enabled) row.classList.add("disabled");
      const legend = document.createElement("legend");
      const on = document.createElement("input");
      on.type = "checkbox";
      on.checked = !!step;
      on.name = "enabled";
      on.addEventListener("change", () => toggleStep(plugin, on.checked));
      const label = document.createElement("label");
      label.append(on, " " + plugin);
      legend.append(label);
      if (st && st.enabled && st.kept !== null && st.kept !== undefined) {
        const kept = document.createElement("span");
        kept.className = "kept";
        kept.textContent = " → " + st.kept + " kept";
        legend.append(kept);
      }
      row.append(legend);
      for (const p of params) {
        const label = document.createElement("label");
        label.title = p.help;
        const input = document.createElement(p.choices.length ? "select" : "input");
        input.name = p.key;
        if (p.choices.length) {
          for (const c of [""].concat(p.choices)) {
            const o = document.createElement("option");
            o.value = c;
            o.textContent = c || "(default" + (p.default ? ": " + p.default : "") + ")";
            input.append(o);
          }
        } else {
          input.type = "text";
          input.placeholder = p.default || (plugin === "manual" ? "frames, e.g. 12,40" : "");
          if (plugin === "manual") input.classList.add("frames");
        }
        input.value = shown(step && step[plugin] ? step[plugin][p.key] : null);
        input.disabled = !step;
        input.addEventListener("change", () => setParam(plugin, p.key, input.value));
        input.addEventListener("keydown", (e) => {
          if (e.key === "Enter") {
            e.preventDefault();
            setParam(plugin, p.key, input.value);
          }
        });
        label.append(p.key + " ", input);
        row.append(label);
      }
      if (st && !st.enabled) {
        const why = document.createElement("p");
        why.className = "needs";
        why.textContent = (st.reason || "the project lacks this step's analysis") +
          (st.command ? "; compute it with:" : "");
        row.append(why);
        if (st.command) {
          const code = document.createElement("code");
          code.textContent = st.command;
          const copy = document.createElement("button");
          copy.type = "button";
          copy.textContent = "Copy";
          copy.addEventListener("click", () => {
            navigator.clipboard.writeText(code.textContent).then(
              () => say("command copied"), () => say("copy failed: select the text", true));
          });
          row.append(code, copy);
        }
      }
      form.append(row);
    }
    // Recorded steps (a `reconstruct` of the project): shown, never run or edited here.
    for (const r of (S.sel && S.sel.recorded) || []) {
      const row = document.createElement("fieldset");
      row.id = "step-" + r.plugin;
      row.className = "recorded";
      const legend = document.createElement("legend");
      legend.textContent = r.plugin + " (recorded)";
      const kept = document.createElement("span");
      kept.className = "kept";
      kept.textContent = " → " + r.kept + " kept, " + r.added.length + " added";
      legend.append(kept);
      const note = document.createElement("p");
      note.className = "note";
      note.textContent = r.note;
      const list = document.createElement("ul");
      list.className = "added";
      for (const a of r.added) {
        const item = document.createElement("li");
        item.dataset.frame = String(a.frame);
        item.textContent = "frame " + a.frame + " (round " + a.round + "): " + a.reason;
        item.addEventListener("click", () => setCursor(a.frame));
        list.append(item);
      }
      row.append(legend, note, list);
      form.append(row);
    }
    if (editing) {
      const el = form.querySelector("#" + editing.row + " [name=" + editing.name + "]");
      if (el && !el.disabled) {
        if (editing.text) el.value = editing.value;
        el.focus();
      }
    }
  }

  function toggleStep(plugin, on) {
    let steps = S.steps.filter((s) => stepId(s) !== plugin);
    if (on) {
      const params = {};
      for (const p of S.schema.filter((p) => p.plugin === plugin)) {
        params[p.key] = p.default === null ? null : coerce(p.default);
      }
      if (plugin === "spacing" && params.threshold === null) params.threshold = "auto";
      if (plugin === "manual") {
        params.add = [];
        params.remove = [];
      }
      const kind = S.chain.find((k) => k.id === plugin);
      const required = kind ? kind.required : null;
      if (required && params[required] === null) {
        say(plugin + ": give " + required + " first", true);
      }
      steps.push({ [plugin]: params });
    }
    commit(steps);
  }

  function setParam(plugin, key, text) {
    const steps = JSON.parse(JSON.stringify(S.steps));
    const step = steps.find((s) => stepId(s) === plugin);
    if (!step) return;
    const v = parsed(plugin, text);
    if (JSON.stringify(step[plugin][key]) === JSON.stringify(v)) return;
    step[plugin][key] = v;
    S.inputAt = performance.now();
    commit(steps);
  }

  function toggleKeyframe(f) {
    const by = ((S.sel && S.sel.recorded) || []).find((r) => r.added.some((a) => a.frame === f));
    if (by) {
      say("frame " + f + " was added by " + by.plugin + " (recorded): it stays", true);
      return;
    }
    const steps = JSON.parse(JSON.stringify(S.steps));
    let m = steps.find((s) => stepId(s) === "manual");
    if (!m) {
      m = { manual: { add: [], remove: [] } };
      steps.push(m);
    }
    const add = m.manual.add || [], remove = m.manual.remove || [];
    const drop = (list) => list.splice(list.indexOf(f), 1);
    if (add.includes(f)) drop(add);
    else if (remove.includes(f)) drop(remove);
    else if (S.sel.keyframes.includes(f)) remove.push(f);
    else add.push(f);
    m.manual = { add, remove };
    if (!add.length && !remove.length) steps.splice(steps.indexOf(m), 1);
    S.inputAt = performance.now();
    commit(steps);
  }

  // ----- selection and timeline --------------------------------------------------------------
  async function apply() {
    const seq = ++S.applySeq;
    if (!S.inputAt) S.inputAt = performance.now();
    try {
      const sel = await api("POST", "/api/apply", { steps: S.steps, view: S.view });
      if (seq !== S.applySeq) return;
      S.sel = sel;
      drawSelection();
      say("");
    } catch (e) {
      if (seq !== S.applySeq) return;
      say(e.message, true);
      markError(e.step);
    }
    $("undo").disabled = !S.undo.length;
    $("redo").disabled = !S.redo.length;
    const dirty = JSON.stringify(S.steps) !== S.savedSteps;
    $("dirty").textContent = dirty ? "●" : "";
    document.body.dataset.dirty = dirty ? "1" : "";
  }

  function markError(i) {
    if (i === null || i === undefined || !S.steps[i]) return;
    const row = $("step-" + stepId(S.steps[i]));
    if (row) row.classList.add("error");
  }

  function drawSelection() {
    const sel = S.sel;
    const count = $("kf-count");
    count.dataset.count = String(sel.keyframes.length);
    count.textContent = sel.keyframes.length + " keyframes of " + S.info.input.frames + " frames";
    S.view = { from: sel.layout.from, to: sel.layout.to };
    $("timeline").innerHTML = sel.timeline_svg;
    // The drawing is the report's: its own ids (`timeline`, `cursor`) would clash with the
    // page's, so they become classes; its hidden cursor line is the page's cursor.
    for (const el of $("timeline").querySelectorAll("[id]")) {
      el.classList.add("svg-" + el.id);
      el.removeAttribute("id");
    }
    renderSteps();
    drawStrip();
    drawCursor();
    // The redraw time: from the input to the first frame painted with the new timeline (a
    // task queued from requestAnimationFrame runs after that paint).
    const started = S.inputAt;
    S.inputAt = 0;
    requestAnimationFrame(() => setTimeout(() => {
      window.kfLastRedrawMs = performance.now() - started;
      window.kfLastServerMs = sel.server_ms;
      document.body.dataset.redraws = String(Number(document.body.dataset.redraws || 0) + 1);
    }, 0));
  }

  function svgScale() {
    const svg = $("timeline").querySelector("svg");
    if (!svg) return 1;
    return svg.getBoundingClientRect().width / S.sel.layout.width;
  }

  // x of frame f in the SVG's own units (the server's drawing is layout.width wide).
  function svgX(f) {
    const l = S.sel.layout;
    if (l.to <= l.from) return l.left + l.span / 2;
    return l.left + ((f - l.from) / (l.to - l.from)) * l.span;
  }

  // x of frame f in CSS px from the left edge of the timeline's SVG, and back.
  function xOf(f) {
    return svgX(f) * svgScale();
  }

  function frameAt(x) {
    const l = S.sel.layout, span = Math.max(1, l.to - l.from);
    const f = l.from + Math.round(((x / svgScale() - l.left) / l.span) * span);
    return Math.min(l.to, Math.max(l.from, f));
  }

  // Viewport x of the SVG's left edge.
  function svgLeft() {
    const svg = $("timeline").querySelector("svg");
    return (svg || $("timeline")).getBoundingClientRect().left;
  }

  function drawCursor() {
    const c = $("timeline").querySelector(".svg-cursor");
    if (c) {
      const x = String(svgX(S.cursor));
      c.setAttribute("x1", x);
      c.setAttribute("x2", x);
      c.setAttribute("stroke", "#cc0000");
      c.setAttribute("visibility", "visible");
    }
    for (const fig of $("strip").children) {
      fig.classList.toggle("cursor", Number(fig.dataset.frame) === S.cursor);
    }
    const key = S.sel.keyframes.includes(S.cursor);
    $("view-info").textContent = "frame " + S.cursor + (key ? " (keyframe)" : "") +
      ", view " + S.view.from + "–" + S.view.to;
    showFrame(S.cursor);
  }

  function setCursor(f) {
    const n = S.info.input.frames;
    S.cursor = Math.min(n - 1, Math.max(0, f));
    if (S.cursor < S.view.from || S.cursor > S.view.to) {
      const w = S.view.to - S.view.from;
      const from = Math.min(Math.max(0, S.cursor - Math.floor(w / 2)), Math.max(0, n - 1 - w));
      setView(from, from + w);
    } else {
      drawCursor();
    }
  }

  function setView(from, to) {
    const n = S.info.input.frames;
    // Whole frames: the server reads the view as indices.
    const w = Math.round(Math.min(n - 1, Math.max(19, to - from)));
    from = Math.min(Math.max(0, Math.round(from)), n - 1 - w);
    S.view = { from, to: from + w };
    apply();
  }

  function zoom(factor, around) {
    const f = around === undefined ? S.cursor : around;
    const w = (S.view.to - S.view.from) * factor;
    const t = (f - S.view.from) / Math.max(1, S.view.to - S.view.from);
    setView(f - w * t, f - w * t + w);
  }

  // ----- frames ------------------------------------------------------------------------------
  let hoverTimer = 0;
  function showFrame(f) {
    clearTimeout(hoverTimer);
    hoverTimer = setTimeout(() => {
      const pi = $("preview-image");
      // Without the input (moved, or a synthetic project) there is nothing to decode.
      if (S.info.input.available) pi.src = img("/api/frame/" + f + ".jpg", "large");
      else pi.alt = "frame " + f + ": the input " + S.info.input.path + " is not available";
      const ex = S.exported.get(f);
      const mask = $("preview-mask");
      const kind = ex && ex.mask ? "mask" : ex && ex.overlay ? "overlay" : null;
      mask.hidden = !(S.showMask && kind);
      if (!mask.hidden) mask.src = img("/api/export/" + kind + "/" + f);
      drawScores(f);
    }, 80);
  }

  function drawScores(f) {
    const t = $("scores");
    t.textContent = "";
    const row = (k, v) => {
      const tr = document.createElement("tr");
      const a = document.createElement("th"), b = document.createElement("td");
      a.textContent = k;
      b.textContent = v;
      tr.append(a, b);
      t.append(tr);
    };
    row("frame", f + (S.sel.keyframes.includes(f) ? " (keyframe)" : ""));
    const ts = S.series.timestamps;
    if (ts && ts[f] !== undefined && ts[f] !== null) row("time", ts[f].toFixed(3) + " s");
    for (const c of S.series.curves) {
      const v = c.values[f];
      if (v !== undefined && v !== null) row(c.name, Number(v).toPrecision(5));
    }
  }

  function drawStrip() {
    const strip = $("strip");
    strip.textContent = "";
    const { from, to } = S.view;
    const count = Math.min(12, to - from + 1);
    for (let i = 0; i < count; i++) {
      const f = Math.round(from + (i * (to - from)) / Math.max(1, count - 1));
      const fig = document.createElement("figure");
      fig.dataset.frame = String(f);
      if (S.sel.keyframes.includes(f)) fig.className = "key";
      const im = document.createElement("img");
      im.loading = "lazy";
      if (S.info.input.available) im.src = img("/api/frame/" + f + ".jpg", "strip");
      const cap = document.createElement("figcaption");
      cap.textContent = String(f);
      fig.append(im, cap);
      fig.addEventListener("mouseenter", () => showFrame(f));
      fig.addEventListener("click", () => setCursor(f));
      strip.append(fig);
    }
  }

  // ----- save --------------------------------------------------------------------------------
  async function save() {
    if (S.saving) return;
    S.saving = true;
    try {
      const r = await api("POST", "/api/save", { steps: S.steps, revision: S.revision });
      S.revision = r.revision;
      S.savedSteps = JSON.stringify(S.steps);
      document.body.dataset.revision = String(r.revision);
      say("saved " + r.saved + " (" + r.count + " keyframes)");
      apply();
    } catch (e) {
      say(e.message, true);
    } finally {
      S.saving = false;
    }
  }

  async function saveWorkflow(force) {
    try {
      const r = await api("POST", "/api/save-workflow", { steps: S.steps, force });
      say("saved workflow " + r.saved);
    } catch (e) {
      if (e.status === 409 && !force && confirm(e.message + "\nReplace it?")) return saveWorkflow(true);
      say(e.message, true);
    }
  }

  function undo(from, to) {
    if (!from.length) return;
    to.push(JSON.stringify(S.steps));
    S.steps = JSON.parse(from.pop());
    S.inputAt = performance.now();
    renderSteps();
    apply();
  }

  // ----- keyboard and pointer ----------------------------------------------------------------
  function onKey(e) {
    const t = e.target;
    if (t.matches && t.matches("select, textarea, input:not([type=checkbox]):not([type=button])")) return;
    if ($("help").open) return;
    const ctrl = e.ctrlKey || e.metaKey;
    const keys = S.sel ? S.sel.keyframes : [];
    const next = keys.find((k) => k > S.cursor), prev = keys.slice().reverse().find((k) => k < S.cursor);
    const map = {
      ArrowLeft: () => setCursor(S.cursor - (e.shiftKey ? 10 : 1)),
      ArrowRight: () => setCursor(S.cursor + (e.shiftKey ? 10 : 1)),
      "[": () => prev !== undefined && setCursor(prev),
      "]": () => next !== undefined && setCursor(next),
      PageUp: () => prev !== undefined && setCursor(prev),
      PageDown: () => next !== undefined && setCursor(next),
      Home: () => setCursor(0),
      End: () => setCursor(S.info.input.frames - 1),
      k: () => toggleKeyframe(S.cursor),
      "+": () => zoom(0.5),
      "=": () => zoom(0.5),
      "-": () => zoom(2),
      "0": () => setView(0, S.info.input.frames - 1),
      m: () => { S.showMask = !S.showMask; showFrame(S.cursor); },
      "?": () => $("help").showModal(),
    };
    let act = null;
    if (ctrl && (e.key === "z" || e.key === "Z")) act = () => (e.shiftKey ? undo(S.redo, S.undo) : undo(S.undo, S.redo));
    else if (ctrl && e.key === "y") act = () => undo(S.redo, S.undo);
    else if (ctrl && e.key === "s") act = save;
    else if (!ctrl && !e.altKey) act = map[e.key];
    if (act) {
      e.preventDefault();
      act();
    }
  }

  function wire() {
    const box = $("timeline-box");
    let drag = null;
    $("timeline").addEventListener("mousedown", (e) => {
      if (!S.sel || e.button !== 0) return;
      drag = { x: e.clientX, view: S.view, moved: false };
    });
    window.addEventListener("mouseup", (e) => {
      if (drag && !drag.moved) {
        const f = frameAt(e.clientX - svgLeft());
        S.cursor = f;
        toggleKeyframe(f);
      }
      drag = null;
    });
    box.addEventListener("mousemove", (e) => {
      const x = e.clientX - svgLeft();
      if (drag && Math.abs(e.clientX - drag.x) > 4) {
        drag.moved = true;
        const perPx = (drag.view.to - drag.view.from) / (S.sel.layout.span * svgScale());
        const d = Math.round((drag.x - e.clientX) * perPx);
        setView(drag.view.from + d, drag.view.to + d);
        return;
      }
      if (!S.sel) return;
      S.cursor = frameAt(x);
      drawCursor();
    });
    box.addEventListener("wheel", (e) => {
      e.preventDefault();
      zoom(e.deltaY > 0 ? 1.25 : 0.8, frameAt(e.clientX - svgLeft()));
    }, { passive: false });
    document.addEventListener("keydown", onKey);
    $("save").addEventListener("click", save);
    $("save-workflow").addEventListener("click", () => saveWorkflow(false));
    $("undo").addEventListener("click", () => undo(S.undo, S.redo));
    $("redo").addEventListener("click", () => undo(S.redo, S.undo));
    $("help-button").addEventListener("click", () => $("help").showModal());
    window.addEventListener("beforeunload", (e) => {
      if (document.body.dataset.dirty) e.preventDefault();
    });
  }

  // ----- state and polling -------------------------------------------------------------------
  async function load() {
    const st = await api("GET", "/api/state");
    S.info = st;
    S.chain = st.chain;
    S.schema = st.schema;
    S.series = st.series;
    S.steps = st.steps;
    S.savedSteps = JSON.stringify(st.steps);
    S.revision = st.revision;
    S.exported = new Map(st.export.map((e) => [e.index, e]));
    S.view = { from: 0, to: Math.max(0, st.input.frames - 1) };
    document.title = "keyframer review: " + st.project.name;
    $("name").textContent = st.project.name;
    document.body.dataset.revision = String(st.revision);
    await apply();
    document.body.dataset.ready = "1";
  }

  async function poll() {
    try {
      const s = await api("GET", "/api/status");
      const p = $("progress");
      p.hidden = !s.busy;
      if (s.busy) {
        p.max = s.busy.total || 1;
        p.value = s.busy.done;
        p.title = s.busy.what;
      }
      if (s.revision > S.revision && !S.saving) {
        say("the project was saved in another tab or read again after a change on disk; reloaded");
        S.undo = [];
        S.redo = [];
        await load();
      }
    } catch (e) {
      say("server not answering: " + e.message, true);
    }
  }

  // For the browser tests: the viewport x of frame f on the timeline, the frame at a viewport x,
  // the current keyframes.
  window.kfTest = {
    frameX: (f) => svgLeft() + xOf(f),
    frameAt: (x) => frameAt(x - svgLeft()),
    keyframes: () => (S.sel ? S.sel.keyframes.slice() : []),
  };

  wire();
  load().catch((e) => say(e.message, true));
  setInterval(poll, 1000);
})();
