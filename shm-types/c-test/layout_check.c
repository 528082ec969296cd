/*
 * Checks what a C (or C++) compiler makes of include/uss_shm_types.h against the Rust side of
 * the contract: sizes, alignments and field offsets (uss_shm_types::layout::LAYOUTS), the
 * iceoryx2 type names, constants, code table values and service name patterns.
 *
 * The expected values come from layout_expected.h, which shm-types/tests/c_header.rs writes from
 * the Rust crate for each run, then compiles this file with cc (and c++) and runs it:
 *   cargo test -p uss-shm-types --test c_header
 * Exit status 0 when everything matches; every mismatch is printed.
 */
#include "uss_shm_types.h"

#include <stddef.h>
#include <stdio.h>
#include <string.h>

#ifdef __cplusplus
#define ALIGN_OF(T) alignof(T)
#else
#define ALIGN_OF(T) _Alignof(T)
#endif

static unsigned checks;
static unsigned failures;

static void expect_number(const char *what, unsigned long long found, unsigned long long expected)
{
    checks++;
    if (found != expected) {
        failures++;
        printf("MISMATCH %s: %llu, expected %llu\n", what, found, expected);
    }
}

static void expect_string(const char *what, const char *found, const char *expected)
{
    checks++;
    if (strcmp(found, expected) != 0) {
        failures++;
        printf("MISMATCH %s: \"%s\", expected \"%s\"\n", what, found, expected);
    }
}

#define EXPECT_TYPE(T, size, align)                                                            \
    expect_number("sizeof(" #T ")", sizeof(T), size);                                          \
    expect_number("alignof(" #T ")", ALIGN_OF(T), align);

#define EXPECT_FIELD(T, field, offset, size)                                                   \
    checks++;                                                                                  \
    if (offsetof(T, field) != (offset)) {                                                      \
        failures++;                                                                            \
        printf("MISMATCH " #T "." #field ": offset %zu, expected %zu\n", offsetof(T, field),   \
               (size_t)(offset));                                                              \
    }                                                                                          \
    expect_number("sizeof(" #T "." #field ")", sizeof(((T *)0)->field), size);

#ifdef __cplusplus
/* The C++ bindings of iceoryx2 take the type name from this member. */
#define EXPECT_TYPE_NAME(T, name, expected)                                                    \
    expect_string(#name, name, expected);                                                      \
    expect_string(#T "::IOX2_TYPE_NAME", T::IOX2_TYPE_NAME, expected);
#else
#define EXPECT_TYPE_NAME(T, name, expected) expect_string(#name, name, expected);
#endif

#define EXPECT_NUMBER(name, expected) expect_number(#name, (unsigned long long)(name), expected);

#define EXPECT_STRING(name, expected) expect_string(#name, name, expected);

/* A service name for one drive: pattern with %s (bus), %016llx (generation), %u (address). */
#define EXPECT_DRIVE_NAME(pattern, bus, generation, address, expected)                         \
    {                                                                                          \
        char name[256];                                                                        \
        snprintf(name, sizeof name, pattern, bus, (unsigned long long)(generation), address);  \
        expect_string(#pattern, name, expected);                                               \
    }

/* A service name of one ussd instance: pattern with %s (bus) and %016llx (generation). */
#define EXPECT_INSTANCE_NAME(pattern, bus, generation, expected)                               \
    {                                                                                          \
        char name[256];                                                                        \
        snprintf(name, sizeof name, pattern, bus, (unsigned long long)(generation));           \
        expect_string(#pattern, name, expected);                                               \
    }

/* A name for the whole bus: pattern with %s (bus). */
#define EXPECT_BUS_NAME(pattern, bus, expected)                                                \
    {                                                                                          \
        char name[256];                                                                        \
        snprintf(name, sizeof name, pattern, bus);                                             \
        expect_string(#pattern, name, expected);                                               \
    }

int main(void)
{
#include "layout_expected.h"
    printf("layout_check: %u checks, %u failed\n", checks, failures);
    return failures == 0 ? 0 : 1;
}
