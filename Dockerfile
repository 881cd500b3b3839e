# twinmill as a container image: `docker build -t twinmill:latest .` — the entry point is the
# command line, so `docker run twinmill:latest study run /study/X.manifest.json` runs a
# shard (deploy/k8s/study-job.yaml).
FROM rust:1-bookworm AS build
WORKDIR /src
COPY . .
RUN cargo build --release --locked --bin twinmill

FROM debian:bookworm-slim
COPY --from=build /src/target/release/twinmill /usr/local/bin/twinmill
ENTRYPOINT ["twinmill"]
