# cloud2cnc: one image for the API and the workers.
#
#   docker build -t cloud2cnc .
#   docker run -p 8000:8000 -v cloud2cnc-data:/data cloud2cnc                 # API only (default CMD)
#   docker run -v cloud2cnc-data:/data -e CELERY_BROKER_URL=redis://... \
#              -e DATABASE_URL=postgresql://... cloud2cnc cloud2cnc worker     # a worker
#
# docker-compose.yml runs redis, postgres, the API and N workers from this image.
# Every dependency installs from wheels on python:3.11-slim, so no compiler is needed. torch's CPU build is
# installed first from PyTorch's own index: the package's bound (<2.14) is then met and pip does not pull the
# multi-GB CUDA build. For GPU workers, build from an image with CUDA and drop that line.

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    CLOUD2CNC_DATA_DIR=/data

# The source is only needed to build the package; the installed copy lives in site-packages.
COPY . /tmp/src
RUN pip install "torch>=2.4,<2.14" --index-url https://download.pytorch.org/whl/cpu \
    && pip install /tmp/src \
    && rm -rf /tmp/src \
    && useradd --system --uid 10001 --user-group --create-home --home-dir /home/cloud2cnc cloud2cnc \
    && mkdir -p /data \
    && chown cloud2cnc:cloud2cnc /data

# A new named volume mounted here starts as a copy of this directory, owned by the non-root user.
VOLUME ["/data"]
USER cloud2cnc
WORKDIR /home/cloud2cnc
EXPOSE 8000

# Liveness of the API (the image has no curl; Python's urllib does the request).
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4).status != 200)"]

# The API alone: workers run as their own containers (`cloud2cnc worker`).
CMD ["cloud2cnc", "serve", "--host", "0.0.0.0", "--port", "8000", "--no-worker"]
