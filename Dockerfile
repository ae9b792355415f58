FROM python:3.11-slim
WORKDIR /srv/gsa
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 GSA_DATA_DIR=/data GSA_HOST=0.0.0.0 GSA_PORT=8000
COPY pyproject.toml README.md alembic.ini ./
COPY app ./app
COPY planner ./planner
COPY inference ./inference
COPY scene ./scene
COPY migrations ./migrations
# torch==2.13.0 from PyPI is a CUDA build on x86_64 (several GB); for a slim image, install the
# CPU wheel of the same version from PyTorch's CPU index first, then the package.
RUN pip install --no-cache-dir torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu \
 && pip install --no-cache-dir -e . && mkdir -p /data
VOLUME /data
EXPOSE 8000
# Ready when the database answers at the code's schema and the models are loaded (503 otherwise).
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s \
  CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/readyz', timeout=4)"
# `gsa serve` applies the Alembic migrations, then starts uvicorn.
CMD ["gsa", "serve"]
