// Mounts studio-base's App (exported onto window by its UMD bundle) with what a host must give it: settings and
// layouts kept in memory, no extensions, and the data sources radseek uses: a Foxglove WebSocket (radseek view)
// and an MCAP file (flight.mcap), chosen by the URL as in Foxglove: ?ds=foxglove-websocket&ds.url=ws://...
// The layout in layout.json beside this page (or the file &layoutFile= names) is stored as "radseek": add
// &layoutId=radseek to open with it.
(async function main() {
  const api = window;

  class MemoryConfiguration {
    constructor() { this.values = new Map(); this.listeners = new Map(); }
    get(key) { return this.values.get(key); }
    async set(key, value) {
      this.values.set(key, value);
      for (const cb of this.listeners.get(key) ?? []) cb(value);
    }
    addChangeListener(key, cb) {
      if (!this.listeners.has(key)) this.listeners.set(key, new Set());
      this.listeners.get(key).add(cb);
    }
    removeChangeListener(key, cb) { this.listeners.get(key)?.delete(cb); }
  }

  class MemoryLayouts {
    constructor() { this.namespaces = new Map(); }
    space(ns) {
      if (!this.namespaces.has(ns)) this.namespaces.set(ns, new Map());
      return this.namespaces.get(ns);
    }
    async list(ns) { return [...this.space(ns).values()]; }
    async get(ns, id) { return this.space(ns).get(id); }
    async put(ns, layout) { this.space(ns).set(layout.id, layout); return layout; }
    async delete(ns, id) { this.space(ns).delete(id); }
    async importLayouts({ fromNamespace, toNamespace }) {
      for (const layout of this.space(fromNamespace).values()) this.space(toNamespace).set(layout.id, layout);
    }
  }

  await api.initI18n();
  // a first visit: the 3D panel's one-time settings tooltip would cover part of the scene
  if (localStorage.getItem("studio.profile-data") == undefined) {
    localStorage.setItem("studio.profile-data",
                         JSON.stringify({ onboarding: { settingsTooltipShownForPanelTypes: ["3D"] } }));
  }
  const layouts = new MemoryLayouts();
  const response = await fetch(new URLSearchParams(window.location.search).get("layoutFile") ?? "layout.json");
  if (response.ok) {
    const data = await response.json();
    // "local": studio-base's LayoutManager.LOCAL_STORAGE_NAMESPACE
    await layouts.put("local", { id: "radseek", name: "radseek", permission: "CREATOR_WRITE",
                                 baseline: { data, savedAt: new Date().toISOString() },
                                 working: undefined, syncInfo: undefined });
  }
  const props = {
    deepLinks: [window.location.href],
    appConfiguration: new MemoryConfiguration(),
    dataSources: [new api.FoxgloveWebSocketDataSourceFactory(), new api.McapLocalDataSourceFactory(),
                  new api.RemoteDataSourceFactory()],
    layoutStorage: layouts,
    extensionLoaders: [],
    enableGlobalCss: true,
    enableLaunchPreferenceScreen: false,
  };
  window.ReactDOM.render(window.React.createElement(api.App, props), document.getElementById("root"));
})().catch((err) => {
  console.error(err);
  document.body.setAttribute("data-viewer-error", String(err));
});
