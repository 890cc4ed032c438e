// Drawing of each view as SVG (no library): DarkRoom grids, Reach projections, bandit feature bars.
"use strict";
const SVGNS = "http://www.w3.org/2000/svg";
const MOVES = [[0, 1], [0, -1], [-1, 0], [1, 0], [0, 0]];  // up, down, left, right, stay (families/darkroom/env.py)
const ACTIONS = ["up", "down", "left", "right", "stay"];
let animation = null;

function el(parent, tag, attrs, text) {
  const node = document.createElementNS(SVGNS, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  parent.appendChild(node);
  return node;
}

function panel(title, w, h) {
  const div = document.createElement("div");
  div.className = "panel";
  const svg = document.createElementNS(SVGNS, "svg");
  svg.setAttribute("width", w);
  svg.setAttribute("height", h);
  div.appendChild(svg);
  const caption = document.createElement("div");
  caption.textContent = title;
  div.appendChild(caption);
  document.getElementById("view").appendChild(div);
  return svg;
}

function grid(svg, size, px) {  // y up, as the terminal's grid
  for (let x = 0; x < size; x++) for (let y = 0; y < size; y++)
    el(svg, "rect", {class: "cell", x: x * px, y: y * px, width: px, height: px});
  return (c, off = 0) => [(c[0] + 0.5 + off) * px, (size - c[1] - 0.5 + off) * px];
}

function goalMark(svg, at, px) {
  el(svg, "rect", {class: "goal", x: at[0] - px / 2 + 2, y: at[1] - px / 2 + 2, width: px - 4, height: px - 4, "fill-opacity": 0.35});
  el(svg, "text", {x: at[0] - 5, y: at[1] + 5, "font-size": 14}, "G");
}

function animate(steps, frame) {  // replay the episodes' steps, looping, one every 60 ms
  let h = 0;
  animation = setInterval(() => { frame(h); h = (h + 1) % steps; }, 60);
}

function moves(svg, at, px, p) {  // the agent's cell (black) and its two proposed moves as arrows (stay: a ring)
  [[p.first, "first", -0.15], [p.second, "second", 0.15]].forEach(([a, cls, off], k) => {
    const [dx, dy] = MOVES[a], from = at(p.cell, off), to = at([p.cell[0] + dx, p.cell[1] + dy], off);
    if (a === 4) {
      const c = at(p.cell);
      el(svg, "circle", {class: cls, cx: c[0], cy: c[1], r: px * (0.3 + 0.08 * k), style: "fill:none", "stroke-width": 4});
      el(svg, "text", {class: cls, x: from[0] + px * 0.4, y: from[1] - px * 0.3, "font-size": 18}, String(k + 1));
      return;
    }
    const ux = (to[0] - from[0]) / px, uy = (to[1] - from[1]) / px, head = px * 0.3;  // unit direction
    el(svg, "line", {class: cls, x1: from[0], y1: from[1], x2: to[0] - ux * head, y2: to[1] - uy * head, "stroke-width": 6});
    el(svg, "polygon", {class: cls, points: [to, [to[0] - ux * head - uy * head / 2, to[1] - uy * head + ux * head / 2],
                                             [to[0] - ux * head + uy * head / 2, to[1] - uy * head - ux * head / 2]]
                                             .map(q => q.join(",")).join(" ")});
    el(svg, "text", {class: cls, x: to[0] + 6 * Math.abs(uy) + 4, y: to[1] - 6 * Math.abs(ux) - 4, "font-size": 18}, String(k + 1));
  });
  const c = at(p.cell);
  el(svg, "circle", {cx: c[0], cy: c[1], r: 7, fill: "#000"});
}

function drawDarkroomSteps(p) {
  const px = 44, svg = panel("the agent (black) and its two moves", p.size * px, p.size * px);
  const at = grid(svg, p.size, px);
  goalMark(svg, at(p.goal), px);
  moves(svg, at, px, p);
  return `Goal G at (${p.goal}). Agent at (${p.cell}). 1 (blue): ${ACTIONS[p.first]}; 2 (orange): ${ACTIONS[p.second]}.`;
}

function drawOnlineDarkroom(p) {  // an online agent's question: its episode so far, its moves, its context
  const px = 40, svg = panel(`task ${p.task}: the episode so far (grey) and the two moves the agent asks about`,
                             p.size * px, p.size * px);
  const at = grid(svg, p.size, px);
  if (p.goal !== null) goalMark(svg, at(p.goal), px);
  if (p.path.length > 1) el(svg, "polyline", {class: "path", style: "stroke:#777", points: p.path.map(c => at(c).join(",")).join(" ")});
  moves(svg, at, px, p);
  const div = document.createElement("div");
  div.className = "panel context";
  const said = {first: "≻", second: "≺", equal: "=", skip: "?"};
  div.textContent = `its context (${p.context.length} answered):`;
  for (const q of p.context.slice(-12)) {
    const line = document.createElement("div");
    line.textContent = `at (${q.cell}): ${ACTIONS[q.first]} ${said[q.answer]} ${ACTIONS[q.second]}`;
    div.appendChild(line);
  }
  document.getElementById("view").appendChild(div);
  return `Goal G at (${p.goal}). Return so far this episode: ${p.return}. 1 (blue): ${ACTIONS[p.first]}; ` +
         `2 (orange): ${ACTIONS[p.second]}.`;
}

function drawDarkroomTrajectories(p) {
  const px = 44, svg = panel("two episodes (1 blue, 2 orange; squares: start), replayed step by step", p.size * px, p.size * px);
  const at = grid(svg, p.size, px);
  if (p.goal !== null) goalMark(svg, at(p.goal), px);
  const dots = [];
  [[p.first, "first", -0.12], [p.second, "second", 0.12]].forEach(([path, cls, off]) => {
    el(svg, "polyline", {class: `path ${cls}`, points: path.map(c => at(c, off).join(",")).join(" ")});
    const s = at(path[0], off);
    el(svg, "rect", {class: cls, x: s[0] - 6, y: s[1] - 6, width: 12, height: 12});
    dots.push([el(svg, "circle", {class: `dot ${cls}`, r: 8}), path, off]);
  });
  const label = el(svg, "text", {x: 4, y: 14, "font-size": 12}, "");
  animate(p.first.length, h => {
    for (const [dot, path, off] of dots) { const c = at(path[h], off); dot.setAttribute("cx", c[0]); dot.setAttribute("cy", c[1]); }
    label.textContent = `step ${h + 1} / ${p.first.length}`;
  });
  const visits = path => path.filter(c => c[0] === p.goal[0] && c[1] === p.goal[1]).length;
  if (p.goal === null) return "Which episode is better?";
  return `Goal G at (${p.goal}). Steps on the goal: 1 (blue) ${visits(p.first)}, 2 (orange) ${visits(p.second)}.`;
}

function drawReachTrajectories(p) {  // top view (x, y) and side view (x, z) of the end-effector paths
  const all = p.first.concat(p.second, [p.goal]);
  const views = [["top view (x, y)", 0, 1], ["side view (x, z)", 0, 2]];
  const dots = [];
  for (const [title, i, j] of views) {
    const w = 320, m = 20, lo = [0, 1, 2].map(k => Math.min(...all.map(q => q[k])));
    const hi = [0, 1, 2].map(k => Math.max(...all.map(q => q[k])));
    const span = Math.max(hi[i] - lo[i], hi[j] - lo[j], 1e-3);
    const at = q => [m + (q[i] - lo[i]) / span * (w - 2 * m), w - m - (q[j] - lo[j]) / span * (w - 2 * m)];
    const svg = panel(title, w, w);
    for (const [path, cls] of [[p.first, "first"], [p.second, "second"]]) {
      el(svg, "polyline", {class: `path ${cls}`, points: path.map(q => at(q).join(",")).join(" ")});
      const s = at(path[0]);
      el(svg, "rect", {class: cls, x: s[0] - 4, y: s[1] - 4, width: 8, height: 8});
      dots.push([el(svg, "circle", {class: `dot ${cls}`, r: 6}), path, at]);
    }
    const g = at(p.goal);
    el(svg, "circle", {class: "goal", cx: g[0], cy: g[1], r: 8});
    el(svg, "text", {x: g[0] + 9, y: g[1] + 4, "font-size": 13}, "goal");
  }
  animate(p.first.length, h => {
    for (const [dot, path, at] of dots) { const c = at(path[h]); dot.setAttribute("cx", c[0]); dot.setAttribute("cy", c[1]); }
  });
  const dist = path => Math.hypot(...[0, 1, 2].map(k => path[path.length - 1][k] - p.goal[k])).toFixed(3);
  return `Hand paths (squares: start). Final distance to the goal: 1 (blue) ${dist(p.first)}, 2 (orange) ${dist(p.second)}.`;
}

function drawBanditDuels(p) {  // θ (what is wanted) beside the two arms' features, one bar group per dimension
  const d = p.goal.length, w = 40 * d + 40, h = 260, mid = h / 2, top = Math.max(...p.goal.concat(p.first, p.second).map(Math.abs));
  const svg = panel("features per dimension: θ (green), arm 1 (blue), arm 2 (orange)", w, h);
  el(svg, "line", {x1: 20, x2: w - 20, y1: mid, y2: mid, stroke: "#999"});
  for (let k = 0; k < d; k++) {
    [[p.goal[k], "goal"], [p.first[k], "first"], [p.second[k], "second"]].forEach(([v, cls], b) => {
      const len = v / top * (mid - 20);
      el(svg, "rect", {class: cls, x: 24 + 40 * k + 11 * b, width: 10, y: len > 0 ? mid - len : mid, height: Math.abs(len)});
    });
    el(svg, "text", {x: 30 + 40 * k, y: h - 4, "font-size": 11}, `d${k}`);
  }
  return `Arm 1 is arm #${p.arms[0]}, arm 2 is arm #${p.arms[1]}. The better arm's features point along θ.`;
}

const DRAW = {darkroom_steps: drawDarkroomSteps, online_darkroom: drawOnlineDarkroom, darkroom_trajectories: drawDarkroomTrajectories,
              reach_trajectories: drawReachTrajectories, bandit_duels: drawBanditDuels};

function draw(p) {
  if (animation !== null) { clearInterval(animation); animation = null; }
  document.getElementById("view").replaceChildren();
  return DRAW[p.view](p);
}
