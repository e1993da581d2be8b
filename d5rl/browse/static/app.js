// d5rl browse: the page.  Plain JavaScript, one view per route (#/, #/task/ID, #/task/ID/episode/I, #/runs),
// data from the JSON endpoints of d5rl/browse/server.py, plots by Plotly.js (served locally).
"use strict";

const app = document.getElementById("app");
const PLOT_CONFIG = { displaylogo: false, responsive: true };

function h(tag, attrs = {}, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "onclick") el.addEventListener("click", v);
    else if (k === "text") el.textContent = v;
    else el.setAttribute(k, v);
  }
  for (const c of children.flat()) if (c != null) el.append(c instanceof Node ? c : String(c));
  return el;
}

async function api(path) {
  const r = await fetch(path);
  const body = await r.json();
  if (!r.ok) throw new Error(body.error + (body.hint ? `\n(${body.hint})` : ""));
  return body;
}

const num = (x, d = 3) => (x == null ? "–" : Number(x).toFixed(d));
const bytes = (n) => {
  const u = ["B", "KiB", "MiB", "GiB", "TiB"]; let i = 0;
  while (n >= 1024 && i < u.length - 1) { n /= 1024; i++; }
  return `${i ? n.toFixed(1) : n} ${u[i]}`;
};
const enc = encodeURIComponent;

function showError(e) { app.append(h("p", { class: "error", text: String(e.message || e) })); }

// --- tasks ----------------------------------------------------------------------------------------
async function tasksView() {
  const data = await api("/api/tasks");
  app.replaceChildren(h("h1", { text: "Tasks and datasets" }),
    h("p", { class: "muted", text: "Click a task with data on disk to see its dataset and episodes. " +
      "Datasets not generated yet: `d5rl generate TASK`." }));
  const rows = data.tasks.map((t) => {
    const d = t.dataset, disk = t.on_disk;
    const tr = h("tr", { class: "link", "data-task": t.id, onclick: () => (location.hash = `#/task/${t.id}`) },
      h("td", {}, h("a", { href: `#/task/${t.id}`, text: t.id })), h("td", { text: t.observation }),
      h("td", { text: t.horizon }), h("td", { text: d ? `${d.name} v${d.version}` : "–" }),
      h("td", { text: d ? `${disk ? disk.episodes : 0} / ${d.episodes}` : "–" }), h("td", { text: t.status }),
      h("td", { text: disk ? bytes(disk.bytes) : "–" }),
      h("td", { text: t.score ? `${num(t.score.random, 2)} / ${num(t.score.expert, 2)}` : "–" }));
    return tr;
  });
  app.append(h("table", {}, h("tr", {}, ["task", "observation", "horizon", "dataset", "episodes on disk / total",
    "status", "size on disk", "score refs (random / expert return)"].map((c) => h("th", { text: c }))), rows));
}

function titledPlot(title, cls) {
  // the title is HTML above the plot, so Plotly's tool bar (top right of the plot) cannot cover it
  const div = h("div", { class: `plot ${cls}` });
  return [h("div", { class: "plot-box" }, h("div", { class: "plot-title", text: title }), div), div];
}

// --- one task: its dataset ------------------------------------------------------------------------
function barPlot(div, p) {
  Plotly.newPlot(div, [{ type: "bar", x: p.x, y: p.y, width: p.width, marker: { color: "#4c78a8" } }], {
    margin: { l: 50, r: 10, t: 30, b: 40 },
    xaxis: { title: { text: p.xlabel } }, yaxis: { title: { text: p.ylabel } }, bargap: p.width ? 0.02 : 0.2,
  }, PLOT_CONFIG);
}

async function taskView(task) {
  const t = await api(`/api/tasks/${enc(task)}`);
  app.replaceChildren(h("h1", { text: t.id }), h("p", { text: t.description }));
  const info = [["observation", t.observation], ["horizon", `${t.horizon} steps`], ["status", t.status],
    ["score", t.score_definition]];
  if (t.score) info.push(["score references", `random ${num(t.score.random)}, expert ${num(t.score.expert)} (${t.score.source})`]);
  if (t.dataset) info.push(["dataset", `${t.dataset.name} v${t.dataset.version}, ${t.dataset.episodes} episodes, ` +
    `seed ${t.dataset.seed}, generator ${t.dataset.generator}`], ["", t.dataset.description]);
  if (t.on_disk) info.push(["on disk", `${t.on_disk.episodes} episodes, ${t.on_disk.transitions} transitions, ${bytes(t.on_disk.bytes)}`]);
  app.append(h("table", {}, info.map(([k, v]) => h("tr", {}, h("th", { text: k }), h("td", { text: v })))));
  if (t.datacard) {
    const pre = h("pre", { class: "card", text: "…" });
    const det = h("details", {}, h("summary", { text: `Data card (docs/datacards/${t.datacard})` }), pre);
    det.addEventListener("toggle", async () => { if (det.open) pre.textContent = await (await fetch(`/api/datacards/${t.datacard}`)).text(); });
    app.append(det);
  }
  if (!t.on_disk) { app.append(h("p", { class: "muted", text: `No data on disk: run \`d5rl generate ${t.id}\`.` })); return; }
  app.append(h("h2", { text: "Dataset overview" }));
  const grid = h("div", { class: "grid", id: "overview" }, h("span", { class: "muted", text: "computing…" }));
  app.append(grid, h("h2", { text: "Episodes" }));
  const table = h("div", { id: "episodes" }, h("span", { class: "muted", text: "loading…" }));
  app.append(table);
  const [ov, eps] = await Promise.all([api(`/api/tasks/${enc(task)}/overview`), api(`/api/tasks/${enc(task)}/episodes`)]);
  grid.replaceChildren();
  for (const p of ov.plots) { const [box, div] = titledPlot(p.title, ""); grid.append(box); barPlot(div, p); }
  episodeTable(table, t.id, eps);
}

function episodeTable(container, task, eps) {
  const n = eps.lengths.length;
  let order = [...Array(n).keys()], key = "index", desc = false;
  const cols = [["index", (i) => i], ["length", (i) => eps.lengths[i]], ["return", (i) => eps.returns[i]]];
  if (eps.scores) cols.push(["normalized score", (i) => eps.scores[i]]);
  const render = () => {
    const get = cols.find((c) => c[0] === key)[1];
    order.sort((a, b) => (desc ? -1 : 1) * ((get(a) ?? -Infinity) - (get(b) ?? -Infinity)));
    const head = h("tr", {}, cols.map(([c]) => h("th", { class: "sortable", text: c + (c === key ? (desc ? " ▼" : " ▲") : ""),
      onclick: () => { desc = c === key ? !desc : true; key = c; render(); } })));
    const rows = order.slice(0, 300).map((i) => h("tr", { class: "link", "data-episode": i,
      onclick: () => (location.hash = `#/task/${task}/episode/${i}`) },
      cols.map(([c, g]) => h("td", { text: c === "index" || c === "length" ? g(i) : num(g(i)) }))));
    container.replaceChildren(h("p", { class: "muted", text: `${n} episodes` + (n > 300 ? " (first 300 in this order)" : "") +
      "; click a column to sort, a row to watch the episode." }), h("table", {}, head, rows));
  };
  render();
}

// --- one episode: frames, scrubber, plots ---------------------------------------------------------
let stopPlayback = () => {};

async function episodeView(task, index) {
  const ep = await api(`/api/tasks/${enc(task)}/episodes/${index}`);
  const T = ep.length;
  const nav = h("p", {},
    h("a", { href: `#/task/${task}`, text: `← ${task}` }), "  ",
    index > 0 ? h("a", { href: `#/task/${task}/episode/${index - 1}`, text: "‹ previous" }) : null, "  ",
    index + 1 < ep.episodes ? h("a", { href: `#/task/${task}/episode/${index + 1}`, text: "next ›" }) : null);
  app.replaceChildren(nav, h("h1", { text: `${task}: episode ${index} of ${ep.episodes}` }),
    h("p", { text: `${T} steps, return ${num(ep.return)}` + (ep.score != null ? `, normalized score ${num(ep.score)}` : "") +
      (ep.terminal ? ", ends in a terminal state" : ", ends at the time limit") }),
    h("details", {}, h("summary", { text: "episode metadata" }), h("pre", { class: "card", text: JSON.stringify(ep.meta, null, 1) })));
  const frames = h("div", { class: "frames", id: "frames" }, h("span", { class: "muted", text: "loading frames (rendering them the first time)…" }));
  const scrub = h("input", { type: "range", min: 0, max: T, value: 0, id: "scrubber" });
  const label = h("span", { id: "frame-label" });
  const play = h("button", { id: "play", text: "▶ play" });
  app.append(frames, h("div", { class: "controls" }, play, scrub, label));
  const plots = ep.panels.map((p) => { const d = h("div", { class: "wide plot-panel" }); app.append(d); return [d, p]; });
  let cams = [], frame = 0;

  const setFrame = (f) => {
    frame = Math.max(0, Math.min(T, f));
    scrub.value = frame;
    label.textContent = `frame ${frame} / ${T}` + (frame < T ? ` · reward ${num(ep.panels[0].series[0].y[frame])}` : "");
    document.body.dataset.frame = frame;
    for (const c of cams) {
      const k = Math.min(frame, c.frames - 1), r = Math.floor(k / c.cols), col = k % c.cols;
      c.div.style.backgroundPosition = `-${col * c.width * c.scale}px -${r * c.height * c.scale}px`;
    }
    const line = { type: "line", xref: "x", yref: "paper", x0: frame, x1: frame, y0: 0, y1: 1, line: { color: "#d62728", width: 1.5 } };
    for (const [d] of plots) if (d.layout) Plotly.relayout(d, { shapes: [line] });
  };

  for (const [d, p] of plots) {
    const x = [...Array(p.series[0].y.length).keys()];
    const traces = p.series.map((s, j) => p.kind === "flags"
      ? { x, y: s.y.map((v) => (v == null ? null : j + 0.8 * v)), name: s.name, mode: "lines", line: { shape: "hv" } }
      : { x, y: s.y, name: s.name, mode: "lines", yaxis: s.axis === "y2" ? "y2" : "y" });
    // left-aligned: Plotly's tool bar sits at the top right
    const layout = { title: { text: p.title + (p.align === "transition" ? " (per transition t: frame t → t+1)" : " (per frame)"),
      font: { size: 12 }, x: 0, xanchor: "left", xref: "paper" },
      margin: { l: p.kind === "flags" || p.value_labels ? 110 : 50, r: 60, t: 28, b: 28 }, xaxis: { range: [0, T] }, legend: { font: { size: 10 } }, showlegend: p.series.length > 1 };
    if (p.series.some((s) => s.axis === "y2")) layout.yaxis2 = { overlaying: "y", side: "right", title: { text: "return" } };
    if (p.kind === "flags") layout.yaxis = { tickvals: p.series.map((_, j) => j), ticktext: p.series.map((s) => s.name) };
    if (p.value_labels) layout.yaxis = { tickvals: p.value_labels.map((_, j) => j), ticktext: p.value_labels };
    Plotly.newPlot(d, traces, layout, PLOT_CONFIG);
    d.on("plotly_click", (ev) => setFrame(Math.round(ev.points[0].x)));
  }
  scrub.addEventListener("input", () => setFrame(Number(scrub.value)));
  let timer = null;
  stopPlayback = () => { clearInterval(timer); timer = null; play.textContent = "▶ play"; };
  play.addEventListener("click", () => {
    if (timer) return stopPlayback();
    if (frame >= T) setFrame(0);
    play.textContent = "❚❚ pause";
    timer = setInterval(() => (frame >= T ? stopPlayback() : setFrame(frame + 1)), 50);
  });
  setFrame(0);

  try {
    const fr = await api(`/api/tasks/${enc(task)}/episodes/${index}/frames`);
    frames.replaceChildren();
    cams = fr.cameras.map((c) => {
      const scale = Math.max(1, Math.round(240 / c.height));
      const div = h("div", { class: "frame", "data-camera": c.name,
        style: `width:${c.width * scale}px;height:${c.height * scale}px;background-size:${c.cols * c.width * scale}px auto;` });
      const img = new Image();
      img.onload = () => { div.style.backgroundImage = `url(${img.src})`; div.dataset.loaded = "1"; };
      img.src = `/api/tasks/${enc(task)}/episodes/${index}/frames/${enc(c.name)}`;
      frames.append(h("div", { class: "camera" }, div, h("div", { text: `${c.name} (${c.width}×${c.height}, ${fr.source})` })));
      return { ...c, div, scale };
    });
    setFrame(frame);
  } catch (e) {
    frames.replaceChildren(h("span", { class: "muted", text: `No frames: ${e.message}` }));
  }
}

// --- benchmark runs ---------------------------------------------------------------------------------
// Per task: a table of every agent of every run next to the paper's value (sortable, best mean highlighted),
// learning curves for agents evaluated more than once, final scores per seed for the others.
const COLORS = ["#4c78a8", "#f58518", "#54a24b", "#e45756", "#72b7b2", "#b279a2", "#ff9da6", "#9d755d", "#eeca3b", "#79706e"];
const DASHES = ["solid", "dash", "dot", "dashdot", "longdash"];
const SYMBOLS = ["circle", "square", "diamond", "triangle-up", "cross"];

function compareTable(task, phase, entries) {
  const best = Math.max(...entries.map((e) => e.row.mean));
  const cols = [
    ["agent", (e) => e.label, (e) => e.label],
    ["steps", (e) => e.row.steps, (e) => e.row.steps],
    ["seeds", (e) => String(e.row.n), (e) => e.row.n],
    ["mean ± std", (e) => e.row.text, (e) => e.row.mean],
    ["95% CI of the mean", (e) => e.row.ci_text, (e) => e.row.ci[0]],
    [`paper (${entries[0].row.paper_task})`, (e) => e.row.paper_text, (e) => (e.row.paper ? e.row.paper[0] : null)],
  ];
  let key = 3, desc = true;
  const table = h("table", { class: "scores compare", "data-task": task, "data-phase": phase });
  const render = () => {
    const get = cols[key][2];
    const order = [...entries].sort((a, b) => {
      const x = get(a), y = get(b);
      const c = typeof x === "string" ? x.localeCompare(y) : (x ?? -Infinity) - (y ?? -Infinity);
      return desc ? -c : c;
    });
    table.replaceChildren(h("tr", {}, cols.map(([c], j) => h("th", { class: "sortable", "data-col": c,
      text: c + (j === key ? (desc ? " ▼" : " ▲") : ""), onclick: () => { desc = j === key ? !desc : j !== 0; key = j; render(); } }))),
      ...order.map((e) => h("tr", { class: e.row.mean === best ? "best" : "", "data-run": e.run.label, "data-algo": e.row.algo },
        cols.map(([c, text]) => h("td", { text: text(e) })))));
  };
  render();
  return table;
}

async function runsView() {
  const { runs } = await api("/api/tasks");
  app.replaceChildren(h("h1", { text: "Benchmark runs" }));
  if (!runs.length) {
    app.append(h("p", { class: "muted", text: "No run directories: start the page with `d5rl browse RUN_DIR [RUN_DIR ...]` " +
      "(the --out directories of `d5rl bench`)." }));
    return;
  }
  const all = await Promise.all(runs.map((r) => api(`/api/runs/${r.index}`)));
  const label = (run, method) => (all.length > 1 ? `${run.label}: ${method}` : method);
  const methods = [...new Set(all.flatMap((r) => r.methods))];
  const envs = all[0].environments;
  const envOf = Object.fromEntries(all.flatMap((r) => r.tasks.map((t) => [t.task, t.environment])));
  const envRank = (e) => (envs.includes(e) ? envs.indexOf(e) : envs.length);
  const tasks = Object.keys(envOf).sort((a, b) => envRank(envOf[a]) - envRank(envOf[b]) ||
    envOf[a].localeCompare(envOf[b]) || a.localeCompare(b));
  app.append(h("p", { class: "muted", text: "Per task, each agent's final normalized score: mean ± std over seeds " +
    "(as in the run's report.md), the 95% bootstrap interval of the mean over seeds, and the paper's mean ± std " +
    "for the task's row (500k steps on the paper's own data; a -state task is compared with its camera task). " +
    "Click a column to sort; the best mean is highlighted. " +
    (all.length > 1 ? "Agents are named by their run's path relative to the runs' common folder, then the method. " : "") +
    "Plots: learning curves where an agent was evaluated more than once, otherwise its final score per seed." }));
  const style = (run, algo) => ({ color: COLORS[methods.indexOf(algo) % COLORS.length],
    dash: DASHES[run.index % DASHES.length], symbol: SYMBOLS[run.index % SYMBOLS.length] });
  for (const task of tasks) {
    const section = h("section", { class: "task-runs", "data-task": task });
    section.append(h("h2", { text: task }, h("span", { class: "muted", text: `  ${envOf[task]}` })));
    const body = h("div", { class: "task-body" });
    const tables = h("div", { class: "tables" });
    body.append(tables);
    section.append(body);
    app.append(section);
    const last = {};  // agent key -> its entry of the last phase, for the dot plot
    const phases = ["offline", "online"].filter((ph) => all.some((run) => (run.tables[ph] || []).some((r) => r.task === task)));
    for (const phase of phases) {
      const entries = all.flatMap((run) => (run.tables[phase] || []).filter((r) => r.task === task)
        .map((row) => ({ run, row, phase, label: label(run, row.method) })));
      for (const e of entries) last[`${e.run.index}/${e.row.algo}`] = e;
      tables.append(h("h3", { text: phase === "offline" ? "Final offline score" : "After online fine-tuning" }),
        compareTable(task, phase, entries));
    }
    const curves = all.flatMap((run) => run.curves.filter((c) => c.task === task).map((c) => ({ run, c })));
    const multi = curves.filter(({ c }) => c.steps.length > 1);
    if (multi.length) {
      const [box, div] = titledPlot("Learning curves (mean ± std over seeds)", "curve");
      body.append(box);
      const traces = [];
      for (const { run, c } of multi) {
        const name = `${label(run, c.method)} (${c.seeds} seeds)`, st = style(run, c.algo);
        traces.push({ x: c.steps.concat([...c.steps].reverse()), y: c.mean.map((m, i) => m + c.std[i]).concat(c.mean.map((m, i) => m - c.std[i]).reverse()),
          fill: "toself", line: { width: 0 }, fillcolor: st.color, opacity: 0.15, showlegend: false, hoverinfo: "skip", legendgroup: name });
        traces.push({ x: c.steps, y: c.mean, name, mode: "lines+markers", legendgroup: name,
          line: { color: st.color, dash: st.dash }, marker: { symbol: st.symbol, size: 5 } });
      }
      Plotly.newPlot(div, traces, { margin: { l: 50, r: 10, t: 30, b: 40 }, xaxis: { title: { text: "steps" } },
        yaxis: { title: { text: "normalized score" } }, legend: { font: { size: 9 } } }, PLOT_CONFIG);
    }
    const single = curves.filter(({ c }) => c.steps.length <= 1).map(({ run, c }) => last[`${run.index}/${c.algo}`]).filter(Boolean);
    if (single.length) {
      const [box, div] = titledPlot("Final score per seed (one evaluation per run)", "dots");
      body.append(box);
      // one row per agent (horizontal, so that long run labels stay readable), a dot per seed, a tick at the paper's mean
      const rowLabel = (e) => (phases.length > 1 ? `${e.label} (${e.phase})` : e.label);
      const traces = single.map((e) => {
        const st = style(e.run, e.row.algo);
        return { type: "scatter", mode: "markers", name: e.label, y: e.row.scores.map(() => rowLabel(e)), x: e.row.scores,
          text: e.row.seeds.map((s) => `seed ${s}`), hovertemplate: "%{text}: %{x:.3f}<extra>%{y}</extra>",
          marker: { color: st.color, symbol: st.symbol, size: 9, opacity: 0.8 }, showlegend: false };
      });
      const paper = single.filter((e) => e.row.paper);
      if (paper.length) traces.push({ type: "scatter", mode: "markers", name: "paper's mean", y: paper.map(rowLabel),
        x: paper.map((e) => e.row.paper[0]), marker: { symbol: "line-ns-open", size: 16, color: "#222", line: { width: 2 } },
        hovertemplate: "paper: %{x:.3f}<extra>%{y}</extra>" });
      div.style.height = `${90 + 22 * single.length}px`;
      Plotly.newPlot(div, traces, { margin: { l: 10, r: 10, t: 30, b: 40 }, xaxis: { title: { text: "normalized score" }, zeroline: true },
        yaxis: { automargin: true, autorange: "reversed", tickfont: { size: 10 } },
        legend: { orientation: "h", x: 0, y: 1.02, yanchor: "bottom", font: { size: 10 } } }, PLOT_CONFIG);
    }
  }
  const behaviour = all.flatMap((run) => (run.behaviour || []).map((t) => [run, t]));
  if (behaviour.length) {
    app.append(h("h2", { text: "What the agents do (final evaluation)" }), h("p", { class: "muted", text: all[0].behaviour_note }));
    for (const [run, t] of behaviour) {
      app.append(h("h3", { text: all.length > 1 ? `${run.label}: ${t.task}` : t.task }));
      app.append(h("table", { class: "scores" }, h("tr", {}, h("th", { text: "method" }), h("th", { text: "cells" }),
        t.labels.map((l) => h("th", { text: l }))),
        t.rows.map((r) => h("tr", {}, h("td", { text: r.method }), h("td", { text: String(r.cells) }),
          t.keys.map((k) => h("td", { text: r.stats[k] === null ? "–" : num(r.stats[k]) }))))));
    }
  }
  const videos = all.flatMap((run) => run.cells.flatMap((c) => c.videos.map((v) => [run, c, v])));
  if (videos.length) {
    app.append(h("h2", { text: "Rollout videos" }));
    app.append(h("div", { class: "grid" }, videos.map(([run, c, v]) => h("div", { class: "camera" },
      v.endsWith(".gif") ? h("img", { src: `/api/runs/${run.index}/files/${v.split("/").map(enc).join("/")}` })
        : h("video", { controls: "", preload: "metadata", src: `/api/runs/${run.index}/files/${v.split("/").map(enc).join("/")}` }),
      h("div", { text: `${label(run, c.method)} · ${c.task} · seed ${c.seed} · ${v.split("/").pop()}` })))));
  }
}

// --- routing ----------------------------------------------------------------------------------------
async function route() {
  stopPlayback();
  const parts = location.hash.replace(/^#\/?/, "").split("/").map(decodeURIComponent);
  app.replaceChildren(h("span", { class: "muted", text: "Loading…" }));
  try {
    if (parts[0] === "task" && parts[2] === "episode") await episodeView(parts[1], Number(parts[3]));
    else if (parts[0] === "task") await taskView(parts[1]);
    else if (parts[0] === "runs") await runsView();
    else await tasksView();
  } catch (e) { showError(e); }
  document.body.dataset.ready = location.hash;
}
window.addEventListener("hashchange", route);
route();
