# syntax=docker/dockerfile:1
# The Glimpse render service as a container image (issue #6).
#
#   docker build -t glimpse .
#   docker run -p 8080:8080 -v glimpse-data:/data glimpse
#   docker run -p 8080:8080 -e GLIMPSE_TOKEN=secret glimpse      # /v1 needs a bearer token
#
# Two stages: a full Rust toolchain builds a release binary; the runtime image holds only
# that binary (SQLite, the viewer page and the example scenes are compiled in; it links
# libstdc++ for the FLIP metric), curl for the health check and an unprivileged user.

FROM rust:1-bookworm AS build
WORKDIR /src

# Dependencies first, against stub sources, so that editing the project's own code does
# not rebuild every crate. The bench sources come along only because the manifest names
# them ([[bench]]); `|| true`: if the stub build cannot work (a new target), the real
# build below simply does all the work.
COPY Cargo.toml Cargo.lock ./
COPY benches ./benches
RUN mkdir -p src \
 && echo 'fn main() {}' > src/main.rs \
 && touch src/lib.rs \
 && (cargo build --release --locked --bin glimpse || true) \
 && rm -rf src

# The real build. The sources carry everything embedded at compile time: the viewer
# (src/service/viewer/), the bundled example scenes (scenes/) and the migrations.
COPY . .
RUN touch src/main.rs src/lib.rs \
 && cargo build --release --locked --bin glimpse \
 && install -D -m 0755 target/release/glimpse /out/glimpse

FROM debian:bookworm-slim AS runtime
RUN apt-get update \
 && apt-get install -y --no-install-recommends curl ca-certificates libstdc++6 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --user-group --home-dir /data --shell /usr/sbin/nologin glimpse \
 && mkdir -p /data \
 && chown glimpse:glimpse /data
COPY --from=build /out/glimpse /usr/local/bin/glimpse

USER glimpse
WORKDIR /data
# Jobs, their statistics and final images (the embedded database) live here: keep it on a
# volume so that accepted jobs survive a restart (service-api.md, "Durability").
VOLUME ["/data"]
EXPOSE 8080
ENV RUST_LOG=info
HEALTHCHECK --interval=30s --timeout=3s --start-period=10s --retries=3 \
  CMD curl -fsS http://127.0.0.1:8080/healthz >/dev/null || exit 1
# `docker stop` sends SIGTERM, which `glimpse serve` handles like Ctrl-C: a graceful stop.
CMD ["glimpse", "serve", "--addr", "0.0.0.0:8080", "--data", "/data"]
