// Vite build of the dashboard: static files only (hashed names under assets/), no CDN, nothing
// fetched at run time; `proden serve` embeds the result (web/CMakeLists.txt).
import { defineConfig } from 'vite';

export default defineConfig({
  base: '/',
  build: {
    target: 'es2022',
    sourcemap: false,
    assetsInlineLimit: 0,
    chunkSizeWarningLimit: 200,
  },
  server: {
    // `npm run dev` against a running daemon: PRODEN_URL=http://127.0.0.1:8080 npm run dev
    proxy: {
      '/api': process.env.PRODEN_URL ?? 'http://127.0.0.1:8080',
      '/metrics': process.env.PRODEN_URL ?? 'http://127.0.0.1:8080',
    },
  },
  test: {
    include: ['tests/unit/**/*.test.ts'],
    environment: 'node',
  },
});
