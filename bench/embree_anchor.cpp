// bench/embree_anchor.cpp: Embree 3's own C++ API on kdray's rays, the anchor of the
// ray benchmarks (bench/embree_anchor.py builds and drives it; no Python in the timed
// part). A server on stdin/stdout, so that a Python script can time it in turns with
// the other ray casters on the same machine state:
//
//   embree_anchor SCENE [CONFIG]
//                              SCENE: uint32 nv, nf; float32 vertices (nv, 3);
//                              uint32 faces (nf, 3). Builds the scene (default flags
//                              and build quality, as Embree's users get them), then
//                              prints "ready BUILD_SECONDS". CONFIG: rtcNewDevice's
//                              string ("verbose=3": the tree's statistics, which
//                              Embree prints on std::cout, sent to stderr).
//   rays PATH N                reads N rays, float32 (N, 8): origin, tnear, direction,
//                              tfar. Prints "ok".
//   trace1                     rtcIntersect1 on every ray, TBB's parallel_for over
//                              blocks of 64 rays (incoherent context). Prints "ok S".
//   trace16 W H                the rays as an H x W image in rows: rtcIntersect16 on
//                              4 x 4 tiles (coherent context; W and H multiples of 4).
//                              Prints "ok S".
//   occluded1                  rtcOccluded1 on every ray, as trace1 (its answers kept
//                              apart: dump writes the last trace's). Prints "ok S N",
//                              N the rays occluded.
//   dump PATH                  writes the last trace's hits: float32 t (N,) (+inf on a
//                              miss), then int32 prim (N,) (-1 on a miss). Prints "ok".
//   quit
//
// Threads: TBB's default, every core (Embree's build and the traces).
#include <embree3/rtcore.h>
#include <tbb/parallel_for.h>
#include <tbb/blocked_range.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <limits>
#include <string>
#include <vector>

// ray q of the rays (8 floats: origin, tnear, direction, tfar) into an RTCRay
static void set_ray(RTCRay &ray, const float *q)
{
    ray.org_x = q[0]; ray.org_y = q[1]; ray.org_z = q[2];
    ray.tnear = q[3];
    ray.dir_x = q[4]; ray.dir_y = q[5]; ray.dir_z = q[6];
    ray.tfar = q[7];
    ray.time = 0.0f;
    ray.mask = 0xFFFFFFFFu;
    ray.id = 0;
    ray.flags = 0;
}

// f(context, i) for rays i < n, over TBB's parallel_for in blocks of 64 rays, each
// block with its own incoherent context (single rays in no order)
template <class F>
static void each_ray(size_t n, F f)
{
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 64),
                      [&](const tbb::blocked_range<size_t> &r) {
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        context.flags = RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
        for (size_t i = r.begin(); i < r.end(); i++)
            f(context, i);
    });
}

static double now()
{
    return std::chrono::duration<double>(
        std::chrono::steady_clock::now().time_since_epoch()).count();
}

static bool read_file(const std::string &path, std::vector<char> &out)
{
    FILE *f = std::fopen(path.c_str(), "rb");
    if (!f) return false;
    std::fseek(f, 0, SEEK_END);
    long n = std::ftell(f);
    std::fseek(f, 0, SEEK_SET);
    out.resize(n);
    bool ok = std::fread(out.data(), 1, n, f) == (size_t)n;
    std::fclose(f);
    return ok;
}

int main(int argc, char **argv)
{
    if (argc != 2 && argc != 3) {
        std::fprintf(stderr, "usage: embree_anchor SCENE [CONFIG]\n");
        return 2;
    }
    std::vector<char> scene_bytes;
    if (!read_file(argv[1], scene_bytes) || scene_bytes.size() < 8) {
        std::fprintf(stderr, "embree_anchor: cannot read %s\n", argv[1]);
        return 1;
    }
    uint32_t nv, nf;
    std::memcpy(&nv, scene_bytes.data(), 4);
    std::memcpy(&nf, scene_bytes.data() + 4, 4);
    const float *vertices = (const float *)(scene_bytes.data() + 8);
    const uint32_t *faces = (const uint32_t *)(scene_bytes.data() + 8 + 12 * (size_t)nv);

    std::cout.rdbuf(std::cerr.rdbuf());   // stdout is the protocol's (printf)
    RTCDevice device = rtcNewDevice(argc == 3 ? argv[2] : nullptr);
    double t0 = now();
    RTCScene scene = rtcNewScene(device);
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *vb = (float *)rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                 RTC_FORMAT_FLOAT3, 3 * sizeof(float), nv);
    std::memcpy(vb, vertices, 12 * (size_t)nv);
    uint32_t *ib = (uint32_t *)rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0,
                                                       RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), nf);
    std::memcpy(ib, faces, 12 * (size_t)nf);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);
    std::printf("ready %.6f\n", now() - t0);
    std::fflush(stdout);

    std::vector<float> rays;          // (N, 8)
    std::vector<float> t_out;
    std::vector<int32_t> prim_out;
    std::vector<uint8_t> occluded_out;
    size_t n = 0;
    std::string cmd;
    while (std::cin >> cmd) {
        if (cmd == "rays") {
            std::string path;
            std::cin >> path >> n;
            std::vector<char> bytes;
            if (!read_file(path, bytes) || bytes.size() != 32 * n) {
                std::printf("error cannot read %zu rays from %s\n", n, path.c_str());
                std::fflush(stdout);
                continue;
            }
            rays.resize(8 * n);
            std::memcpy(rays.data(), bytes.data(), bytes.size());
            t_out.assign(n, 0.0f);
            prim_out.assign(n, -1);
            occluded_out.assign(n, 0);
            std::printf("ok\n");
        } else if (cmd == "trace1") {
            double s = now();
            each_ray(n, [&](RTCIntersectContext &context, size_t i) {
                RTCRayHit rh;
                set_ray(rh.ray, &rays[8 * i]);
                rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
                rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
                rtcIntersect1(scene, &context, &rh);
                bool hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
                t_out[i] = hit ? rh.ray.tfar : std::numeric_limits<float>::infinity();
                prim_out[i] = hit ? (int32_t)rh.hit.primID : -1;
            });
            std::printf("ok %.9f\n", now() - s);
        } else if (cmd == "occluded1") {
            double s = now();
            each_ray(n, [&](RTCIntersectContext &context, size_t i) {
                RTCRay ray;
                set_ray(ray, &rays[8 * i]);
                rtcOccluded1(scene, &context, &ray);
                occluded_out[i] = ray.tfar < 0.0f;    // -inf where occluded
            });
            double seconds = now() - s;
            size_t count = 0;
            for (size_t i = 0; i < n; i++)
                count += occluded_out[i];
            std::printf("ok %.9f %zu\n", seconds, count);
        } else if (cmd == "trace16") {
            size_t w, h;
            std::cin >> w >> h;
            if (w % 4 || h % 4 || w * h != n) {
                std::printf("error %zu x %zu is not the rays' image in 4 x 4 tiles\n", w, h);
                std::fflush(stdout);
                continue;
            }
            size_t tiles_x = w / 4, tiles = tiles_x * (h / 4);
            double s = now();
            tbb::parallel_for(tbb::blocked_range<size_t>(0, tiles, 16),
                              [&](const tbb::blocked_range<size_t> &r) {
                RTCIntersectContext context;
                rtcInitIntersectContext(&context);
                context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
                for (size_t tile = r.begin(); tile < r.end(); tile++) {
                    size_t x0 = 4 * (tile % tiles_x), y0 = 4 * (tile / tiles_x);
                    alignas(64) RTCRayHit16 rh;
                    alignas(64) int valid[16];
                    size_t index[16];
                    for (int k = 0; k < 16; k++) {
                        size_t i = (y0 + k / 4) * w + x0 + k % 4;
                        const float *q = &rays[8 * i];
                        index[k] = i;
                        valid[k] = -1;
                        rh.ray.org_x[k] = q[0]; rh.ray.org_y[k] = q[1]; rh.ray.org_z[k] = q[2];
                        rh.ray.tnear[k] = q[3];
                        rh.ray.dir_x[k] = q[4]; rh.ray.dir_y[k] = q[5]; rh.ray.dir_z[k] = q[6];
                        rh.ray.tfar[k] = q[7];
                        rh.ray.time[k] = 0.0f;
                        rh.ray.mask[k] = 0xFFFFFFFFu;
                        rh.ray.id[k] = 0;
                        rh.ray.flags[k] = 0;
                        rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
                        rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
                    }
                    rtcIntersect16(valid, scene, &context, &rh);
                    for (int k = 0; k < 16; k++) {
                        bool hit = rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID;
                        t_out[index[k]] = hit ? rh.ray.tfar[k] : std::numeric_limits<float>::infinity();
                        prim_out[index[k]] = hit ? (int32_t)rh.hit.primID[k] : -1;
                    }
                }
            });
            std::printf("ok %.9f\n", now() - s);
        } else if (cmd == "dump") {
            std::string path;
            std::cin >> path;
            FILE *f = std::fopen(path.c_str(), "wb");
            bool ok = f && std::fwrite(t_out.data(), 4, n, f) == n
                      && std::fwrite(prim_out.data(), 4, n, f) == n;
            if (f) std::fclose(f);
            std::printf(ok ? "ok\n" : "error cannot write %s\n", path.c_str());
        } else if (cmd == "quit") {
            break;
        } else {
            std::printf("error unknown command %s\n", cmd.c_str());
        }
        std::fflush(stdout);
    }
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    return 0;
}
