/// <reference types="vitest/config" />
import { defineConfig } from "vite";

// The map is served by the backend at `/`: relative asset URLs, everything bundled
// (no CDN at run time). `npm run dev` proxies the API to a running `slidewatch run`.
export default defineConfig({
  base: "./",
  build: { outDir: "dist", emptyOutDir: true, sourcemap: false, chunkSizeWarningLimit: 800 },
  server: {
    proxy: {
      "/api": "http://127.0.0.1:8000",
      "/app-config.json": "http://127.0.0.1:8000",
    },
  },
  test: { environment: "happy-dom", include: ["src/**/*.test.ts"], setupFiles: ["src/i18n/testSetup.ts"] },
});
