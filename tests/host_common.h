/*
 * What the C test hosts (tests/native_host.c, tests/fmu/wrapper_host.c) share: their error
 * exit, the FMI 2.0 logger, reading a file, an XML attribute of a tag, a CSV line's fields.
 * Each host defines HOST_NAME (its messages' prefix) before it includes this header after
 * fmi2Functions.h.
 */
#ifndef FHOBS_HOST_COMMON_H
#define FHOBS_HOST_COMMON_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The message on stderr, prefixed with the host's name; `code` returned. */
static int fail(int code, const char *format, ...)
{
    va_list args;
    va_start(args, format);
    fprintf(stderr, "%s: ", HOST_NAME);
    vfprintf(stderr, format, args);
    fprintf(stderr, "\n");
    va_end(args);
    return code;
}

/* An FMU's log message on stderr: "[instance] status <n> <category>: <message>". */
static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s] status %d %s: ", instance ? instance : "?", (int)status,
            category ? category : "");
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

/* The whole file at path, NUL-terminated (NULL if it cannot be read). */
static char *read_file(const char *path)
{
    /* read in chunks: files of /proc report a size of 0 */
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    size_t size = 0, capacity = 1 << 16;
    char *text = malloc(capacity);
    while (text) {
        size += fread(text + size, 1, capacity - size - 1, f);
        if (size < capacity - 1)
            break;
        char *grown = realloc(text, capacity *= 2);
        if (!grown)
            free(text);
        text = grown;
    }
    if (text)
        text[size] = '\0';
    fclose(f);
    return text;
}

/* The value of attribute `name` inside the tag [tag, end): copied to out, 0 if absent. */
static int attribute(const char *tag, const char *end, const char *name, char *out, size_t size)
{
    char key[64];
    snprintf(key, sizeof key, " %s=\"", name);
    const char *start = strstr(tag, key);
    if (!start || start >= end)
        return 0;
    start += strlen(key);
    const char *stop = strchr(start, '"');
    if (!stop || (size_t)(stop - start) >= size)
        return 0;
    memcpy(out, start, (size_t)(stop - start));
    out[stop - start] = '\0';
    return 1;
}

/* The comma-separated fields of line (at most max), its line end cut. */
static int split(char *line, char **fields, int max)
{
    int count = 0;
    line[strcspn(line, "\r\n")] = '\0';
    for (char *tok = strtok(line, ","); tok && count < max; tok = strtok(NULL, ","))
        fields[count++] = tok;
    return count;
}

#endif
