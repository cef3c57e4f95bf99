/*
 * Runs every file named on the command line through the fuzz target once: the seed corpus
 * becomes a regression test in the ordinary and sanitizer builds, where libFuzzer is absent.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int main(int argc, char **argv)
{
    int i;
    for (i = 1; i < argc; ++i) {
        FILE *file = fopen(argv[i], "rb");
        uint8_t *buffer;
        long size;
        if (file == NULL || fseek(file, 0, SEEK_END) != 0 || (size = ftell(file)) < 0 ||
            fseek(file, 0, SEEK_SET) != 0) {
            fprintf(stderr, "cannot read %s\n", argv[i]);
            return 1;
        }
        buffer = (uint8_t *)malloc((size_t)size + 1U);
        if (buffer == NULL || fread(buffer, 1, (size_t)size, file) != (size_t)size) {
            fprintf(stderr, "cannot read %s\n", argv[i]);
            return 1;
        }
        fclose(file);
        (void)LLVMFuzzerTestOneInput(buffer, (size_t)size);
        free(buffer);
    }
    printf("%d seeds replayed\n", argc - 1);
    return 0;
}
