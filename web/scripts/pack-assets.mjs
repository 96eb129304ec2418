// Packs the built dashboard (Vite's output directory) into the one file `proden serve` embeds
// (service/daemon/web_assets.hpp documents the format): each file with its MIME type, a content
// ETag, whether it may be cached forever (Vite's hashed assets/), and a gzip copy when that is
// smaller. Deterministic: same input, same bytes.
// Usage: node scripts/pack-assets.mjs DIST_DIR OUT_FILE
import { createHash } from 'node:crypto';
import { readdirSync, readFileSync, statSync, writeFileSync, renameSync } from 'node:fs';
import { join, relative, extname } from 'node:path';
import { gzipSync, constants } from 'node:zlib';

const TYPES = {
  '.html': 'text/html; charset=utf-8',
  '.js': 'text/javascript; charset=utf-8',
  '.mjs': 'text/javascript; charset=utf-8',
  '.css': 'text/css; charset=utf-8',
  '.json': 'application/json',
  '.svg': 'image/svg+xml',
  '.png': 'image/png',
  '.ico': 'image/x-icon',
  '.woff2': 'font/woff2',
  '.txt': 'text/plain; charset=utf-8',
  '.map': 'application/json',
};
const COMPRESSIBLE = new Set(['.html', '.js', '.mjs', '.css', '.json', '.svg', '.txt', '.map', '.ico']);

const [dist, out] = process.argv.slice(2);
if (!dist || !out) {
  console.error('usage: node scripts/pack-assets.mjs DIST_DIR OUT_FILE');
  process.exit(2);
}

function walk(dir) {
  return readdirSync(dir)
    .sort()
    .flatMap((name) => {
      const p = join(dir, name);
      return statSync(p).isDirectory() ? walk(p) : [p];
    });
}

const files = [];
const chunks = [];
let offset = 0;
const push = (buf) => {
  chunks.push(buf);
  const at = offset;
  offset += buf.length;
  return at;
};
for (const file of walk(dist)) {
  const rel = '/' + relative(dist, file).split('\\').join('/');
  const ext = extname(file).toLowerCase();
  const type = TYPES[ext];
  if (!type) {
    console.error(`pack-assets: ${rel}: no MIME type known for "${ext}"`);
    process.exit(1);
  }
  const body = readFileSync(file);
  const entry = {
    path: rel,
    type,
    etag: '"' + createHash('sha256').update(body).digest('hex').slice(0, 20) + '"',
    immutable: rel.startsWith('/assets/'),
    offset: push(body),
    size: body.length,
    gzip_offset: 0,
    gzip_size: 0,
  };
  if (COMPRESSIBLE.has(ext)) {
    const gz = gzipSync(body, { level: constants.Z_BEST_COMPRESSION });
    if (gz.length < body.length * 0.9) {
      entry.gzip_offset = push(gz);
      entry.gzip_size = gz.length;
    }
  }
  files.push(entry);
}
if (!files.some((f) => f.path === '/index.html')) {
  console.error(`pack-assets: ${dist} has no index.html`);
  process.exit(1);
}
const manifest = Buffer.from(JSON.stringify({ files }));
const header = Buffer.from(`PRDNWEB1 ${manifest.length}\n`);
writeFileSync(out + '.tmp', Buffer.concat([header, manifest, ...chunks]));
renameSync(out + '.tmp', out);
const total = files.reduce((a, f) => a + (f.gzip_size || f.size), 0);
console.log(`pack-assets: ${files.length} files, ${total} bytes as served gzipped -> ${out}`);
