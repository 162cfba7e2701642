// The web console's pages (gui/web/server.py has the wire). No framework, no build step:
// the page draws the PNG frames the server renders with the OpenCV console's own drawing
// code, and sends back what the human did with the number of the frame on screen.
"use strict";
const TestbedConsole = (() => {
  const token = new URLSearchParams(location.search).get("token") || "";
  const state = { shownSeq: 0, head: null, replies: [], painted: 0, open: false,
                  latencies: [], points: [], fleet: null };
  window.consoleState = state;  // read by tests and the latency benchmark
  let ws = null;
  let nextId = 1;

  // Served under a reverse proxy's path prefix (/fleet/, /fleet/overview), the sockets
  // are under it too: the prefix is the page's own path less "/" or "/overview".
  const prefix = location.pathname.replace(/\/(overview)?$/, "");

  function wsUrl(path) {
    const scheme = location.protocol === "https:" ? "wss://" : "ws://";
    return scheme + location.host + prefix + path + "?token=" + encodeURIComponent(token);
  }

  function send(msg) {
    if (ws && ws.readyState === WebSocket.OPEN) {
      msg.id = nextId++;
      ws.send(JSON.stringify(msg));
    }
  }

  function parseFrame(buf) {
    const n = new DataView(buf).getUint32(0);
    const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
    return [head, new Blob([new Uint8Array(buf, 4 + n)], { type: "image/png" })];
  }

  function status(text) { document.getElementById("status").textContent = text; }

  function setConn(open) {
    state.open = open;
    const el = document.getElementById("conn");
    el.textContent = open ? "connected" : "disconnected: reconnecting";
    el.className = open ? "here" : "away";
  }

  // Frames are drawn one at a time, newest first: a frame that arrives while another is
  // being decoded replaces it (a human wants the present, not a backlog).
  function frameDrawer(canvas, onDrawn) {
    const ctx = canvas.getContext("2d");
    let waiting = null;
    let busy = false;
    async function drain() {
      busy = true;
      while (waiting) {
        const [head, blob] = waiting;
        waiting = null;
        const bitmap = await createImageBitmap(blob);
        if (canvas.width !== bitmap.width || canvas.height !== bitmap.height) {
          canvas.width = bitmap.width;
          canvas.height = bitmap.height;
        }
        ctx.drawImage(bitmap, 0, 0);
        bitmap.close();
        onDrawn(head);
        // The next animation frame comes once this drawing is committed for paint:
        // the page's own timing of "painted".
        requestAnimationFrame(() => {
          const t = performance.timeOrigin + performance.now();
          state.painted += 1;
          state.latencies.push([head.seq, t - head.t_sent]);
          send({ type: "painted", seq: head.seq, t_sent: head.t_sent, t_painted: t });
        });
      }
      busy = false;
    }
    return (head, blob) => { waiting = [head, blob]; if (!busy) drain(); };
  }

  function connect(path, onFrame, onText) {
    ws = new WebSocket(wsUrl(path));
    ws.binaryType = "arraybuffer";
    ws.onopen = () => { state.fleet = null; setConn(true); };  // a new console's state
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") onText(JSON.parse(ev.data));
      else onFrame(...parseFrame(ev.data));
    };
    ws.onclose = (ev) => {
      setConn(false);
      if (ev.code === 1008 || ev.code === 1006 && !state.everOpen) {
        status("this console's token was refused");
      }
      setTimeout(() => connect(path, onFrame, onText), 1000);
    };
    ws.addEventListener("open", () => { state.everOpen = true; });
  }

  function wireButtons() {
    for (const b of document.querySelectorAll("button[data-button]")) {
      b.addEventListener("click", () => {
        send({ type: "button", name: b.dataset.button, seq: state.shownSeq });
      });
    }
  }

  function showFlags(head) {
    document.getElementById("pause").textContent = head.paused ? "Resume" : "Pause";
    document.getElementById("confirm").style.display = head.confirming_stop ? "flex" : "none";
  }

  function onReply(msg) {
    if (msg.type === "input") {
      state.replies.push(msg);
      status(msg.taken ? "sent" : "not taken: " + msg.why);
    } else if (msg.type === "error") {
      state.replies.push(msg);
      status("error: " + msg.why);
    } else if (msg.type === "history") {
      state.points = msg.points;
    } else if (msg.type === "fleet") {
      state.fleet = msg;
    } else if (msg.type === "session") {  // told to a page left open through a restart
      document.getElementById("notice").textContent = msg.notice;
    }
  }

  // A human with no arm sees that they wait, and the fleet's state (the server's
  // "fleet" text, one per step) instead of an empty image.
  const IDLE_NOTES = {
    paused: "The fleet is paused: Resume (or p, space) lets it go on.",
    stopping: "The trial is stopping.",
    running: "This page shows an arm's camera by itself as soon as the fleet needs you.",
  };

  function setText(id, text) { document.getElementById(id).textContent = String(text); }

  // gui.view.human_label: the name with the index beside it; "human <i>" when unnamed.
  function label(human, name) { return name ? `${name} (human ${human})` : `human ${human}`; }
  // gui.view.place_tag: where a person is, beside their label; nothing when untold.
  function place(where) { return where === "remote" ? ", remote" : where ? ", on site" : ""; }

  function showFleet(doc, me) {
    const table = document.getElementById("fleet-robots");
    document.getElementById("fleet-none").hidden = doc !== null;
    table.hidden = doc === null;
    for (const k of ["successes", "hard_resets", "idle_time", "human_actions"]) {
      setText("f-" + k, doc === null ? "-" : doc[k]);
    }
    setText("f-step", doc === null ? "-" : `${doc.t} of ${doc.steps}`);
    setText("f-rohe", doc === null ? "-" : doc.rohe.toFixed(3));
    const rows = (doc === null ? [] : doc.robots).map((r) => {
      const tr = document.createElement("tr");
      tr.dataset.robot = r.robot;
      const held = r.human === null ? "-"
        : (r.name || `human ${r.human}`) + (r.human === me ? " (you)" : "");
      const waited = r.waited === null || r.waited === undefined ? "-" : `${r.waited} steps`;
      [r.robot, r.mode, held, waited].forEach((text, i) => {
        const td = document.createElement("td");  // textContent: names are not markup
        td.textContent = text;
        if (i === 1) td.className = "mode mode-" + r.mode;
        tr.appendChild(td);
      });
      return tr;
    });
    table.tBodies[0].replaceChildren(...rows);
    showQueue(doc === null ? [] : (doc.queue || []));
  }

  // The arms waiting for a person (the server's "queue": longest wait first), each
  // with its wait in steps: the same number the row's "waited" and the overview's
  // badge say.
  function showQueue(queue) {
    const list = document.getElementById("fleet-queue");
    document.getElementById("queue-title").hidden = queue.length === 0;
    list.hidden = queue.length === 0;
    list.replaceChildren(...queue.map((q) => {
      const li = document.createElement("li");  // textContent: arm names are not markup
      li.dataset.robot = q.robot;
      li.textContent = `${q.robot} (${q.mode}): waited ${q.waited} steps`;
      return li;
    }));
  }

  // The panel takes the frame's place and size; the buttons stay where they are
  // (disabled), so none moves under a finger, nor vanishes under a click, as arms come
  // and go.
  function showIdle(head) {
    const idle = head.phase === "idle";
    document.getElementById("idle").hidden = !idle;
    document.getElementById("frame").hidden = idle;
    if (!idle) return;
    const note = head.stop_requested ? "stopping" : head.paused ? "paused" : "running";
    setText("idle-note", IDLE_NOTES[note]);
    showFleet(state.fleet, head.human);
  }

  const KEYS = new Set(["ArrowUp", "ArrowLeft", "ArrowDown", "ArrowRight", "Enter",
                        "Escape", " "]);

  function humanPage() {
    const canvas = document.getElementById("frame");
    const draw = frameDrawer(canvas, (head) => {
      state.shownSeq = head.seq;
      state.head = head;
      document.getElementById("reset").disabled = head.phase !== "reset";
      for (const b of document.querySelectorAll("#pushes button")) {
        b.disabled = head.phase !== "choose";
      }
      showFlags(head);
      showIdle(head);
    });
    connect("/ws", draw, (msg) => {
      onReply(msg);
      if (msg.type === "fleet" && state.head) showIdle(state.head);
    });
    wireButtons();
    document.addEventListener("keydown", (e) => {
      if (e.repeat || e.ctrlKey || e.metaKey || e.altKey) return;
      if (!KEYS.has(e.key) && e.key.length !== 1) return;
      e.preventDefault();  // arrows must not scroll, space must not press a button
      send({ type: "key", key: e.key, seq: state.shownSeq });
    });
    // A click or a tap on the image: the push of the nearest face marker (server side,
    // gui.keys.action_for_click), in the frame's own pixels whatever the page's zoom.
    canvas.addEventListener("pointerdown", (e) => {
      const r = canvas.getBoundingClientRect();
      const x = (e.clientX - r.left) * canvas.width / r.width;
      const y = (e.clientY - r.top) * canvas.height / r.height;
      send({ type: "click", x, y, seq: state.shownSeq });
    });
  }

  const CURVES = [["successes", "#50d050"], ["human_actions", "#ff9a30"],
                  ["hard_resets", "#ff4040"], ["idle", "#a0a0a0"]];

  function drawCurves(canvas, points) {
    const ctx = canvas.getContext("2d");
    const w = canvas.width, h = canvas.height, pad = 28;
    ctx.fillStyle = "#282828";
    ctx.fillRect(0, 0, w, h);
    if (points.length === 0) return;
    const tMax = Math.max(1, points[points.length - 1].t);
    let yMax = 1;
    for (const p of points) for (const [k] of CURVES) yMax = Math.max(yMax, p[k]);
    ctx.font = "12px sans-serif";
    CURVES.forEach(([k, colour], i) => {
      ctx.strokeStyle = colour;
      ctx.beginPath();
      points.forEach((p, j) => {
        const x = pad + (w - 2 * pad) * p.t / tMax;
        const y = h - pad - (h - 2 * pad) * p[k] / yMax;
        if (j === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
      });
      ctx.stroke();
      ctx.fillStyle = colour;
      ctx.fillText(k.replace("_", " ") + " " + points[points.length - 1][k], pad + i * 140, 14);
    });
    ctx.fillStyle = "#aaa";
    ctx.fillText("t = " + tMax, w - pad - 50, h - 8);
    ctx.fillText(String(yMax), 2, pad);
  }

  // Who is here, as text nodes: a name is the lab's text, never markup.
  function showHumans(humans) {
    const items = [];
    humans.forEach((x, i) => {
      if (i > 0) items.push(document.createTextNode(" \u00b7 "));
      const span = document.createElement("span");
      span.className = x.present ? "here" : "away";
      span.dataset.human = String(x.human);
      span.dataset.where = x.where || "";
      span.textContent = `${label(x.human, x.name)}${place(x.where)}: ` +
        (x.present ? x.phase : "away");
      items.push(span);
    });
    document.getElementById("humans").replaceChildren(...items);
  }

  // One row per human: what the run's records say of them so far (FleetStatus.operators,
  // the same figures as the OpenCV overview's lines); names as text, never markup.
  function showOperators(rows) {
    const table = document.getElementById("operators");
    table.hidden = rows.length === 0;
    table.tBodies[0].replaceChildren(...rows.map((x) => {
      const tr = document.createElement("tr");
      tr.dataset.human = String(x.human);
      [label(x.human, x.name), x.skill.toFixed(2), x.violations.toFixed(2),
       x.reset_steps.toFixed(1), x.latency_steps.toFixed(1), String(x.pushes)]
        .forEach((text, i) => {
          const td = document.createElement("td");
          td.textContent = text;
          if (i > 0) td.className = "num";
          tr.appendChild(td);
        });
      return tr;
    }));
  }

  function overviewPage() {
    const curves = document.getElementById("curves");
    const draw = frameDrawer(document.getElementById("mosaic"), (head) => {
      state.shownSeq = head.seq;
      state.head = head;
      if (head.point && (state.points.length === 0
          || state.points[state.points.length - 1].t !== head.point.t)) {
        state.points.push(head.point);
      }
      const last = state.points[state.points.length - 1];
      if (last) {
        document.getElementById("counters").textContent =
          `t ${last.t}  successes ${last.successes}  hard resets ${last.hard_resets}  ` +
          `human actions ${last.human_actions}  idle ${last.idle}  ROHE ${last.rohe}`;
        // faulted arms, waiting arms, who is away, the newest fault (issue 44)
        document.getElementById("health").textContent = last.health || "all well";
      }
      showHumans(head.humans || []);
      showOperators(head.operators || []);
      showFlags(head);
      drawCurves(curves, state.points);
    });
    connect("/ws/overview", draw, (msg) => { onReply(msg); drawCurves(curves, state.points); });
    wireButtons();
  }

  return { humanPage, overviewPage };
})();
