/*
 * vpak.h: the C interface of vdbcook's runtime reader for .vpak assets.
 *
 * A .vpak file is a cooked OpenVDB sequence cut into segments (runs of
 * consecutive frames); each segment is a set of sections (node arrays,
 * tables, brick ranges, atlas textures) that a GPU is given as they are.
 * This library opens an asset (reading only its tables and metadata), says
 * which segment holds a frame and how large each section of a segment is,
 * and fills buffers you allocate with a segment's GPU-ready bytes:
 * supercompressed sections decompressed, every checksum checked, and the
 * sections validated against each other before the call returns.
 * What each section means and how to sample it: docs/format.md;
 * a walk-through: docs/runtime.md; an example: examples/c/vpak_dump.c.
 *
 * Link: the static library libvpak.a (`cargo build --release -p
 * vdbcook-vpak-c`, in target/release/), then on Linux
 *     -lpthread -ldl -lm -lrt -lutil -lgcc_s -lc
 * (what `cargo rustc -p vdbcook-vpak-c --crate-type staticlib -- --print
 * native-static-libs` prints for your platform).
 *
 * Conventions: every function that can fail returns a vpak_status
 * (VPAK_OK is 0) and leaves a one-line message for vpak_last_error() on the
 * calling thread. A reader may be used from several threads at once (each
 * call is independent; the library reads with positioned reads or from a
 * mapping), but not while vpak_close runs. Counts, frames and segments are
 * 32-bit; sizes and offsets 64-bit. No function keeps a pointer you pass.
 */
#ifndef VPAK_H
#define VPAK_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Status codes. */
typedef int32_t vpak_status;
#define VPAK_OK 0
/* The file could not be opened or read. */
#define VPAK_ERROR_IO 1
/* Not a valid asset: not a .vpak, an unsupported version, truncated, damaged or inconsistent. */
#define VPAK_ERROR_FORMAT 2
/* A null pointer, a frame, segment or section out of range, or buffers that do not fit. */
#define VPAK_ERROR_ARGUMENT 3
/* A bug in this library (caught, never unwound into your code): please report it. */
#define VPAK_ERROR_PANIC 4

/* Section kinds (docs/format.md, "Sections"). */
#define VPAK_KIND_METADATA 1
#define VPAK_KIND_FRAMES 2
#define VPAK_KIND_L1_NODES 3
#define VPAK_KIND_L1_ENTRIES 4
#define VPAK_KIND_L2_NODES 5
#define VPAK_KIND_L2_ENTRIES 6
#define VPAK_KIND_L3_NODES 7
#define VPAK_KIND_TILES 8
#define VPAK_KIND_BRICK_RANGES 9
#define VPAK_KIND_ATLAS 10
#define VPAK_KIND_BRICK_TABLE 11
#define VPAK_KIND_CHANNEL_TABLE 12

/* An open asset. */
typedef struct vpak_reader vpak_reader;

/* One section of a segment, as the GPU is given it. */
typedef struct vpak_section {
    uint32_t kind;        /* VPAK_KIND_* (a kind this header does not name: skip it) */
    uint32_t index;       /* which of its kind: the plane, channel or atlas number */
    uint64_t size;        /* bytes of the GPU-ready (restored) section: allocate this */
    uint64_t offset;      /* its offset in the segment's restored body (as docs/format.md lays it out) */
    uint64_t stored_size; /* bytes the file stores (fewer when supercompressed) */
    uint64_t checksum;    /* XXH3-64 of the GPU-ready bytes */
    uint32_t uploaded;    /* 1 when a renderer uploads it (all but the metadata) */
    uint32_t compressed;  /* 1 when the file stores it supercompressed */
    /* For an atlas (kind 10), the 3D texture it is (zeros for other kinds): */
    uint32_t plane;       /* the plane it belongs to */
    uint32_t format;      /* its texels' format: a code of docs/format.md's format table (0 f32, 1 f16, 2 unorm8, 3 bc4, 4 bc7, 5 unorm16) */
    uint32_t lanes;       /* lanes per texel: 1, 2 or 4 */
    uint32_t extent[3];   /* its size in texels along x, y, z (BC formats: 4x4 blocks along x and y) */
} vpak_section;

/* Where one section goes: `size` bytes at `data`. */
typedef struct vpak_buffer {
    void *data;
    uint64_t size;
} vpak_buffer;

/* Opens the asset at `path` (memory-mapped; the file must not change while
 * open) and checks its header, segment table, and each segment's section
 * table and metadata. On success *out is the reader (close it with
 * vpak_close); on failure *out is NULL. */
vpak_status vpak_open(const char *path, vpak_reader **out);

/* Closes a reader (NULL is ignored). */
void vpak_close(vpak_reader *reader);

/* The message of the last failure on this thread ("" if none yet): valid
 * until the next failing call on this thread. */
const char *vpak_last_error(void);

/* Frames of the whole asset (0 for a NULL reader). */
uint32_t vpak_frame_count(const vpak_reader *reader);

/* Segments of the asset (0 for a NULL reader). */
uint32_t vpak_segment_count(const vpak_reader *reader);

/* Bytes read from the file so far (opening included). */
uint64_t vpak_bytes_read(const vpak_reader *reader);

/* The segment holding frame `frame` of the asset, and the frame's index
 * inside it (the frame number a segment's frame table uses). Either out
 * pointer may be NULL. */
vpak_status vpak_locate(const vpak_reader *reader, uint32_t frame, uint32_t *segment, uint32_t *frame_in_segment);

/* The first frame (counted over the asset) and the frame count of a segment. */
vpak_status vpak_segment_frames(const vpak_reader *reader, uint32_t segment, uint32_t *first_frame, uint32_t *frame_count);

/* The number of sections of a segment. */
vpak_status vpak_section_count(const vpak_reader *reader, uint32_t segment, uint32_t *count);

/* Describes the sections of a segment into `sections`, which has room for
 * exactly `count` (vpak_section_count's) entries, in the segment's order:
 * the order vpak_fill_segment's buffers follow. */
vpak_status vpak_sections(const vpak_reader *reader, uint32_t segment, vpak_section *sections, uint32_t count);

/* Fills one buffer per section of a segment (`count` of them, in
 * vpak_sections' order, each exactly the section's `size` bytes, none
 * overlapping) with its GPU-ready bytes: read, decompressed, checksums
 * checked, then validated as docs/format.md's "Validation" says. The
 * metadata's buffer may have data NULL (it is then skipped). Buffers of
 * 4-byte items (all but the metadata and the atlases) must be 4-byte
 * aligned. Sections are read on several threads. On failure the buffers'
 * contents are unspecified: upload nothing. */
vpak_status vpak_fill_segment(const vpak_reader *reader, uint32_t segment, const vpak_buffer *buffers, uint32_t count);

/* Fills `data` (exactly the section's `size` bytes) with one section of a
 * segment: read, decompressed, its checksums checked, but not validated
 * against the others (vpak_fill_segment does that; vpak_check does it once
 * for the whole asset). */
vpak_status vpak_read_section(const vpak_reader *reader, uint32_t segment, uint32_t section, void *data, uint64_t size);

/* Validates the whole asset, a segment at a time (every byte read): for an
 * import step, not for playback. */
vpak_status vpak_check(const vpak_reader *reader);

/* The sequence's frame rate in frames per second (0 for a NULL reader). An
 * asset older than format version 9 records none: 24. */
double vpak_fps(const vpak_reader *reader);

/* Frame `frame`'s number in the source sequence (fire_1001.vdb is 1001; gaps
 * and steps kept). An asset older than version 9 numbers its frames from 0. */
vpak_status vpak_frame_number(const vpak_reader *reader, uint32_t frame, int64_t *number);

/* The frame (counted from 0) whose source number is `number`; VPAK_ERROR_ARGUMENT if none. */
vpak_status vpak_frame_of_number(const vpak_reader *reader, int64_t number, uint32_t *frame);

/* The asset's index-to-world matrix (row-vector convention: world = [i j k 1] * M),
 * row by row into matrix[16]. A segment's index i is source index i + its
 * index offset (vpak_segment_index_offset); level k's: docs/format.md, "Levels". */
vpak_status vpak_transform(const vpak_reader *reader, double *matrix);

/* The levels of detail stored: first_level to levels - 1. Either out pointer may be NULL. */
vpak_status vpak_levels(const vpak_reader *reader, uint32_t *first_level, uint32_t *levels);

/* Channels of the asset (0 for a NULL reader). */
uint32_t vpak_channel_count(const vpak_reader *reader);

/* A channel's name ("density", "vel.x"), owned by the reader (valid until
 * vpak_close); NULL past the last channel. */
const char *vpak_channel_name(const vpak_reader *reader, uint32_t channel);

/* Where a channel's voxels are (format version 10, docs/format.md "Channel
 * resolutions"; an older asset has every channel at level 0, offset 0).
 * *level: the level of detail whose voxels are the channel's own (0: the
 * asset's voxel size; k: voxels 2^k times as wide, at most 3); half_offset[3]:
 * its voxel centres minus those of that level's voxels, in half level-0
 * voxels per axis. Either out pointer may be NULL. */
vpak_status vpak_channel_resolution(const vpak_reader *reader, uint32_t channel, uint32_t *level, int32_t *half_offset);

/* The levels a channel is stored at: *first_level to *end_level - 1 (its own
 * level, or the asset's first stored level if that is coarser, and its levels
 * of detail). At any other level its bricks and tiles hold only its
 * background: do not sample it there. Either out pointer may be NULL. */
vpak_status vpak_channel_levels(const vpak_reader *reader, uint32_t channel, uint32_t *first_level, uint32_t *end_level);

/* The index-to-world matrix of a channel's voxels at `level` (one of
 * vpak_channel_levels'), row by row into matrix[16] (row-vector convention,
 * as vpak_transform): voxel i of the level's source index space is centred at
 * world [i j k 1] * M. VPAK_ERROR_ARGUMENT for a level the channel is not
 * stored at. */
vpak_status vpak_channel_transform(const vpak_reader *reader, uint32_t channel, uint32_t level, double *matrix);

/* A segment's index offset (source index = segment index + offset), into offset[3]. */
vpak_status vpak_segment_index_offset(const vpak_reader *reader, uint32_t segment, int32_t *offset);

/* The number of channel records of a segment: one per channel, then one per
 * alternate plane of the channels stored in several planes. */
vpak_status vpak_segment_channel_records(const vpak_reader *reader, uint32_t segment, uint32_t *count);

/* A segment's channel records as shaders/vpak.wgsl's VpakChannel reads them:
 * `count` (vpak_segment_channel_records') records of 20 uint32_t into words.
 * They index a tables buffer (the brick tables, kind 11, of the planes that
 * have one in plane order, then the channel tables, kind 12, in channel
 * order, back to back), a ranges buffer (every plane's brick ranges, kind
 * 9, in plane order, back to back) and the atlases as texture slots (the
 * atlas section index). Valid for a segment vpak_fill_segment accepted. */
vpak_status vpak_segment_channels(const vpak_reader *reader, uint32_t segment, uint32_t *words, uint32_t count);

#ifdef __cplusplus
}
#endif

#endif /* VPAK_H */
