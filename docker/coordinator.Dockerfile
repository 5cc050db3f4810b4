# The coordinator image: one static binary, nothing else (no shell, no libc, no curl).
# Built by scripts/build-images.sh, which puts the binary in the build context.
FROM scratch
COPY raytile-coordinator /raytile-coordinator
# Listen on every interface of the container; the token comes from RAYTILE_TOKEN (the
# coordinator refuses a non-loopback address without one).
ENV RAYTILE_LISTEN=0.0.0.0:8080 \
    RAYTILE_DATA_DIR=/data
VOLUME /data
EXPOSE 8080
HEALTHCHECK --interval=5s --timeout=4s --start-period=5s --retries=3 \
    CMD ["/raytile-coordinator", "--healthcheck"]
ENTRYPOINT ["/raytile-coordinator"]
