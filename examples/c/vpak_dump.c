/*
 * vpak_dump: prints what an engine learns of a .vpak asset through
 * include/vpak.h, and a hash of every section's GPU-ready bytes.
 *
 *     vpak_dump ASSET.vpak
 *
 * Build (after `cargo build --release -p vdbcook-vpak-c`):
 *     cc -Wall -Werror -Iinclude examples/c/vpak_dump.c target/release/libvpak.a \
 *        -lpthread -ldl -lm -lrt -lutil -lgcc_s -o vpak_dump
 *
 * Output, one record a line:
 *     asset FRAMES SEGMENTS
 *     fps FPS                                      (%.6f)
 *     levels FIRST_LEVEL LEVELS
 *     transform M00 M01 ... M33                    (index to world, %.6f)
 *     channel C NAME LEVEL HX HY HZ FIRST END      (every channel: its own level, its
 *                                                  offset in half voxels, the levels
 *                                                  FIRST to END - 1 it is stored at)
 *     voxels C M00 M01 ... M33                     (its index to world at level FIRST, %.6f)
 *     frame F SEGMENT FRAME_IN_SEGMENT NUMBER      (every frame; NUMBER: in the source sequence)
 *     segment S FIRST_FRAME FRAME_COUNT SECTIONS   (every segment, then:)
 *     offset X Y Z                                 (its index offset)
 *     records N FNV1A64                            (its channel records, as little-endian bytes)
 *     section KIND INDEX SIZE UPLOADED FNV1A64     (of the GPU-ready bytes, hex; for an
 *             atlas then: texture PLANE FORMAT LANES WIDTH HEIGHT DEPTH)
 * Exit status 0, or 1 with "vpak_dump: error: ..." on stderr.
 */
#include <stdio.h>
#include <stdlib.h>

#include "vpak.h"

static int fail(const char *what) {
    fprintf(stderr, "vpak_dump: error: %s: %s\n", what, vpak_last_error());
    return 1;
}

/* FNV-1a, 64-bit: a hash anyone can recompute. */
static uint64_t fnv1a(const unsigned char *b, uint64_t n) {
    uint64_t h = 0xcbf29ce484222325ull;
    for (uint64_t i = 0; i < n; i++) {
        h = (h ^ b[i]) * 0x100000001b3ull;
    }
    return h;
}

static int dump_segment(vpak_reader *r, uint32_t s) {
    uint32_t first, frames, count;
    if (vpak_segment_frames(r, s, &first, &frames) != VPAK_OK || vpak_section_count(r, s, &count) != VPAK_OK) {
        return fail("segment");
    }
    vpak_section *sections = calloc(count ? count : 1, sizeof *sections);
    vpak_buffer *buffers = calloc(count ? count : 1, sizeof *buffers);
    int status = 1;
    if (!sections || !buffers) {
        fprintf(stderr, "vpak_dump: error: out of memory\n");
        goto done;
    }
    if (vpak_sections(r, s, sections, count) != VPAK_OK) {
        status = fail("sections");
        goto done;
    }
    /* One allocation per section (malloc's alignment suits every kind); the
     * metadata is skipped here and read on its own below. */
    for (uint32_t i = 0; i < count; i++) {
        buffers[i].size = sections[i].size;
        buffers[i].data = sections[i].kind == VPAK_KIND_METADATA ? NULL : malloc(sections[i].size ? sections[i].size : 1);
        if (sections[i].kind != VPAK_KIND_METADATA && !buffers[i].data) {
            fprintf(stderr, "vpak_dump: error: out of memory\n");
            goto done;
        }
    }
    if (vpak_fill_segment(r, s, buffers, count) != VPAK_OK) {
        status = fail("fill");
        goto done;
    }
    printf("segment %u %u %u %u\n", s, first, frames, count);
    int32_t offset[3];
    uint32_t records;
    if (vpak_segment_index_offset(r, s, offset) != VPAK_OK || vpak_segment_channel_records(r, s, &records) != VPAK_OK) {
        status = fail("segment");
        goto done;
    }
    printf("offset %d %d %d\n", offset[0], offset[1], offset[2]);
    uint32_t *words = malloc((records ? records : 1) * 20 * sizeof *words);
    if (!words || vpak_segment_channels(r, s, words, records) != VPAK_OK) {
        free(words);
        status = words ? fail("channel records") : 1;
        goto done;
    }
    unsigned char *le = malloc((records ? records : 1) * 80);
    for (uint32_t i = 0; le && i < records * 20; i++) {
        for (int b = 0; b < 4; b++) {
            le[4 * i + b] = (unsigned char)(words[i] >> (8 * b));
        }
    }
    if (le) {
        printf("records %u %016llx\n", records, (unsigned long long)fnv1a(le, (uint64_t)records * 80));
    }
    free(le);
    free(words);
    for (uint32_t i = 0; i < count; i++) {
        const vpak_section *x = &sections[i];
        if (x->kind == VPAK_KIND_METADATA) {
            buffers[i].data = malloc(x->size ? x->size : 1);
            if (!buffers[i].data) {
                fprintf(stderr, "vpak_dump: error: out of memory\n");
                goto done;
            }
            if (vpak_read_section(r, s, i, buffers[i].data, x->size) != VPAK_OK) {
                status = fail("metadata");
                goto done;
            }
        }
        printf("section %u %u %llu %u %016llx", x->kind, x->index, (unsigned long long)x->size, x->uploaded,
               (unsigned long long)fnv1a(buffers[i].data, x->size));
        if (x->kind == VPAK_KIND_ATLAS) {
            printf(" texture %u %u %u %u %u %u", x->plane, x->format, x->lanes, x->extent[0], x->extent[1], x->extent[2]);
        }
        printf("\n");
    }
    status = 0;
done:
    for (uint32_t i = 0; buffers && i < count; i++) {
        free(buffers[i].data);
    }
    free(buffers);
    free(sections);
    return status;
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: vpak_dump ASSET.vpak\n");
        return 2;
    }
    vpak_reader *r = NULL;
    if (vpak_open(argv[1], &r) != VPAK_OK) {
        return fail("open");
    }
    uint32_t frames = vpak_frame_count(r), segments = vpak_segment_count(r);
    printf("asset %u %u\n", frames, segments);
    uint32_t first_level, levels;
    double m[16];
    if (vpak_levels(r, &first_level, &levels) != VPAK_OK || vpak_transform(r, m) != VPAK_OK) {
        int status = fail("metadata");
        vpak_close(r);
        return status;
    }
    printf("fps %.6f\nlevels %u %u\ntransform", vpak_fps(r), first_level, levels);
    for (int i = 0; i < 16; i++) {
        printf(" %.6f", m[i]);
    }
    printf("\n");
    int status = 0;
    for (uint32_t c = 0; c < vpak_channel_count(r) && status == 0; c++) {
        uint32_t level, first, end;
        int32_t h[3];
        double v[16];
        if (vpak_channel_resolution(r, c, &level, h) != VPAK_OK || vpak_channel_levels(r, c, &first, &end) != VPAK_OK ||
            vpak_channel_transform(r, c, first, v) != VPAK_OK) {
            status = fail("channel");
            break;
        }
        printf("channel %u %s %u %d %d %d %u %u\nvoxels %u", c, vpak_channel_name(r, c), level, h[0], h[1], h[2], first, end, c);
        for (int i = 0; i < 16; i++) {
            printf(" %.6f", v[i]);
        }
        printf("\n");
    }
    for (uint32_t f = 0; f < frames && status == 0; f++) {
        uint32_t s, local, back;
        int64_t number;
        if (vpak_locate(r, f, &s, &local) != VPAK_OK || vpak_frame_number(r, f, &number) != VPAK_OK) {
            status = fail("locate");
        } else if (vpak_frame_of_number(r, number, &back) != VPAK_OK || back != f) {
            status = fail("frame of number");
        } else {
            printf("frame %u %u %u %lld\n", f, s, local, (long long)number);
        }
    }
    for (uint32_t s = 0; s < segments && status == 0; s++) {
        status = dump_segment(r, s);
    }
    vpak_close(r);
    return status;
}
